"""Flight logs beside a video: the clock offset between the video and the log (:mod:`.timesync`), measured from the
camera's rotation (:mod:`.image_rotation`)."""

from .timesync import OffsetEstimate, match_rotations

__all__ = ["OffsetEstimate", "match_rotations"]

"""The built-in sources of the streaming pipeline (:data:`cosemdepth.streaming.SOURCES`): a dataset split or any
stream-mode dataset (:mod:`~cosemdepth.streaming.sources.dataset`), a folder of images with a pose file
(:mod:`~cosemdepth.streaming.sources.flight`), a ROS bag (:mod:`~cosemdepth.streaming.sources.bag`), a video with a
flight log (:mod:`~cosemdepth.streaming.sources.video_log`). Each module registers its source and defines its options
(``DatasetOptions``, ``FlightOptions``, ``BagOptions``, ``VideoLogOptions``)."""

from __future__ import annotations

from .bag import BagOptions, BagSource
from .dataset import DatasetOptions, DatasetSource
from .flight import FlightOptions, FlightSource
from .video_log import VideoLogOptions, VideoLogSource

__all__ = [
    "BagOptions",
    "BagSource",
    "DatasetOptions",
    "DatasetSource",
    "FlightOptions",
    "FlightSource",
    "VideoLogOptions",
    "VideoLogSource",
]

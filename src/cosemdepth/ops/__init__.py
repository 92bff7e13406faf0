"""Low-level tensor operations: TensorFlow-exact resampling and padding, normalisation, cost volumes."""

from .resample import resize_bl1, resize_bl2, resize_nn1, resize_nn2
from .padding import same_padding, Conv2dSame

__all__ = ["resize_bl1", "resize_bl2", "resize_nn1", "resize_nn2", "same_padding", "Conv2dSame"]

"""Low-level tensor operations: TensorFlow-exact resampling and padding, normalisation, cost volumes."""

from .padding import Conv2dSame, same_padding
from .resample import resize_bl1, resize_bl2, resize_nn1, resize_nn2

__all__ = ["resize_bl1", "resize_bl2", "resize_nn1", "resize_nn2", "same_padding", "Conv2dSame"]

"""File formats: atomic writes, our model format, TensorFlow checkpoint reading."""

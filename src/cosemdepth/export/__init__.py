"""Exporting the streaming model for deployment (ONNX)."""

from .onnx import StreamingStep, export_onnx, state_components, state_names

__all__ = ["StreamingStep", "export_onnx", "state_components", "state_names"]

"""Trained models -> ONNX graphs and bundles (torch + onnx)."""

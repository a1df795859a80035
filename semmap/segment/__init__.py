"""Segmentation: the Segmenter protocol, its registry and one module per backend."""

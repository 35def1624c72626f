"""Reconstruction methods: FBP, Kaczmarz, Dremel, RESESOP-Kaczmarz."""

from .result import ReconResult

__all__ = ["ReconResult"]

"""Lamina: research-grade layered materials for Cycles. The extension root delegates to ``addon``."""
from .addon import register, unregister  # noqa: F401

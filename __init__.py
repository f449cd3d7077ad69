"""Lamina: research-grade layered materials for Cycles. The extension root delegates to ``addon``."""
if __package__:  # Blender imports this folder as the extension package; test runners may import it bare
    from .addon import register, unregister  # noqa: F401

"""Shader Editor sidebar, tab "Lamina"."""
import bpy

from . import panels

classes = panels.classes


def register():
    for cls in classes:
        bpy.utils.register_class(cls)


def unregister():
    for cls in reversed(classes):
        bpy.utils.unregister_class(cls)

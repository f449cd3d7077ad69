"""Fixtures shared by the Blender tests."""
import pytest

bpy = pytest.importorskip("bpy")

import addon  # noqa: E402


@pytest.fixture
def registered():
    """Lamina registered for the test (operators, panels, handlers), unregistered afterwards."""
    addon.register()
    yield
    addon.unregister()


@pytest.fixture
def sphere():
    """An active mesh object named "ball" (no geometry needed: operators only use its material slots)."""
    obj = bpy.data.objects.new("ball", bpy.data.meshes.new("ball"))
    bpy.context.scene.collection.objects.link(obj)
    bpy.context.view_layer.objects.active = obj
    return obj

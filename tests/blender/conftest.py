"""Fixtures shared by the Blender tests, and the rule that skips ``version_independent`` tests under Blender 4.2."""
import pytest

bpy = pytest.importorskip("bpy")

import addon  # noqa: E402

# The Blender tests run twice in ``make test``: under bpy 5.0 and under Blender 4.2 LTS, the oldest supported, to check
# that the add-on's use of Blender's API works there. A test marked ``version_independent("why")`` checks what does
# not depend on the Blender version (numpy numerics, a long CLI pipeline whose Blender calls other tests make on 4.2):
# it runs under 5.0 only.
ONLY_UNDER = (5, 0, 0)


def pytest_collection_modifyitems(config, items):
    if bpy.app.version >= ONLY_UNDER:
        return
    for item in items:
        marker = item.get_closest_marker("version_independent")
        if marker is not None:
            why = marker.args[0] if marker.args else "version-independent"
            item.add_marker(pytest.mark.skip(reason=f"run under Blender 5.0 only: {why}"))


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

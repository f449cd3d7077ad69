"""Fixtures shared by the Blender tests, and the rule that skips ``version_independent`` tests under Blender 4.2."""
import pytest

bpy = pytest.importorskip("bpy")

import addon  # noqa: E402

# The Blender tests run twice in ``make test``: under bpy 5.0 and under Blender 4.2 LTS, the oldest supported, to check
# that the add-on's use of Blender's API works there. A test marked ``version_independent("why")`` checks what does
# not depend on the Blender version (numpy numerics, a long CLI pipeline whose Blender calls other tests make on 4.2):
# it runs under 5.0 only. A per-preset sweep marked ``under_4_2_for(*values)`` runs under 4.2 only for the cases
# with one of those parameter values (presets that reach 4.2's own code paths: a conductor without the Metallic BSDF,
# transmission, oriented layers), so that 4.2's API is checked on every structure without rendering every preset twice.
ONLY_UNDER = (5, 0, 0)


def pytest_collection_modifyitems(config, items):
    if bpy.app.version >= ONLY_UNDER:
        return
    for item in items:
        marker = item.get_closest_marker("version_independent")
        if marker is not None:
            why = marker.args[0] if marker.args else "version-independent"
            item.add_marker(pytest.mark.skip(reason=f"run under Blender 5.0 only: {why}"))
        sampled = item.get_closest_marker("under_4_2_for")
        if sampled is not None and not _has_value(item, sampled.args):
            item.add_marker(pytest.mark.skip(reason="run under Blender 5.0 only: under 4.2 this sweep runs for "
                                                    + ", ".join(sampled.args)))


def _has_value(item, values) -> bool:
    """Whether one of the case's parameters is (or, as a tuple, holds) one of ``values``."""
    params = getattr(item, "callspec", None)
    found = set()
    for v in (params.params.values() if params else ()):
        found.update(v if isinstance(v, tuple) else (v,))
    return any(v in found for v in values)


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

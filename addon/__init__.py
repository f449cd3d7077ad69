"""Lamina add-on package.

Importing ``addon`` (and its bpy-free core: ``models``, ``reference``, ``presets``, most of ``bake``) never
imports bpy, so scripts, tests and training code can use the reference without Blender. The Blender layer
is imported by ``register()`` only.
"""


def _blender_modules():
    from . import cli, operators, ui

    return (operators, ui, cli)


def register():
    done = []
    try:
        for module in _blender_modules():
            module.register()
            done.append(module)
    except Exception:  # leave nothing half-registered behind
        for module in reversed(done):
            module.unregister()
        raise


def unregister():
    for module in reversed(_blender_modules()):
        module.unregister()

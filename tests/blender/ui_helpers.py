"""Stand-ins for what Blender gives a panel or a dialog only while it draws: a layout that records what is drawn, and
an operator's properties as plain values."""
from types import SimpleNamespace

import bpy


class Layout:
    """Records what a panel or dialog draws, as (call, args, keywords, enabled there) (bpy's UILayout only exists
    while Blender draws)."""

    def __init__(self, log, parent=None):
        self.log, self.parent = log, parent
        self.enabled, self.alert = True, False

    def _on(self) -> bool:
        return self.enabled and (self.parent is None or self.parent._on())

    def __getattr__(self, name):
        if name in ("row", "column", "box", "split"):
            return lambda *a, **k: Layout(self.log, self)
        return lambda *a, **k: self.log.append((name, a, k, self._on())) or type("Props", (), {})()


def text(log) -> str:
    return "\n".join([str(k.get("text", "")) for _, a, k, _ in log] + [" ".join(map(str, a)) for _, a, k, _ in log])


def props(log) -> list[str]:
    """The properties drawn, in order."""
    return [a[1] for name, a, k, _ in log if name == "prop"]


def operators(log) -> dict:
    """Each operator button drawn: its id -> whether it is enabled."""
    return {a[0]: on for name, a, k, on in log if name == "operator"}


def dialog(operator: str, **values) -> SimpleNamespace:
    """A stand-in for the properties of the registered operator ``operator`` ("add_thin_coat"): its defaults, then
    ``values``."""
    defaults = {}
    for prop in getattr(bpy.ops.lamina, operator).get_rna_type().properties:
        if prop.identifier == "rna_type":
            continue
        if prop.type in ("FLOAT", "INT") and prop.array_length:
            defaults[prop.identifier] = tuple(prop.default_array)
        else:
            defaults[prop.identifier] = prop.default
    return SimpleNamespace(**{**defaults, **values})


def bind(cls, ns, methods) -> SimpleNamespace:
    """``ns`` with the operator class ``cls``'s ``methods`` bound to it, as on an operator instance."""
    for name in methods:
        setattr(ns, name, getattr(cls, name).__get__(ns))
    return ns


def draw_dialog(cls, ns, methods) -> list:
    """What ``cls.draw`` draws for the properties ``ns`` (the log), with the operator's ``methods`` bound to ``ns``."""
    log = []
    ns.layout = Layout(log)
    cls.draw(bind(cls, ns, methods), bpy.context)
    return log


def panel_log(context_material) -> list:
    """What the Lamina panels draw for ``context_material`` (the sub-panels where their poll allows, as in Blender)."""
    from addon.ui import panels

    log = []
    context = SimpleNamespace(material=context_material, scene=bpy.context.scene,
                              window_manager=bpy.context.window_manager, active_object=bpy.context.active_object)
    for cls in panels.classes:
        if issubclass(cls, panels.LaminaSubpanel) and not cls.poll(context):
            continue
        cls.draw(SimpleNamespace(layout=Layout(log)), context)
    return log


def panel_text(context_material) -> str:
    return text(panel_log(context_material))

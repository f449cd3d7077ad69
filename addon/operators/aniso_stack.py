"""Add Anisotropic Stack Material: 1-4 rough interfaces top to bottom, each with its own anisotropic roughness and
tangent rotation, the last a dielectric or a metal, media between them; and the lines the dialog and the panel show
of a stack."""
from __future__ import annotations

import bpy

from .. import presets
from ..models import aniso_stack as model
from ..models.metals import METALS
from .material_ops import (CUSTOM, AddMaterialDialog, add_material, conductor_values, declared, draw_conductor, label,
                           metal_items, preset_items, sigma_a_from_color)

PRESET_ITEMS = preset_items(model.ID, "Set the interfaces and the media between them below")
BASE_ITEMS = [("conductor", "Metal", "The last interface is a metal (complex IOR): brushed metal, car paint's flakes"),
              ("dielectric", "Dielectric", "The last interface is a dielectric: what it refracts is lost (an opaque "
                                           "or very thick layer below), only its reflection shows")]
ROUGHNESS_ITEMS = [
    ("glossy", "Roughness, Anisotropy", "As Blender's Glossy BSDF shows them: α = Roughness², Anisotropy > 0 "
                                        "stretches the highlight across the tangent, < 0 along it (±0.99 at most)"),
    ("alpha", "Alpha X, Y", "The GGX roughness α along each interface's tangent and bitangent (any ratio)")]
METAL_ITEMS = metal_items(METALS, "A base of")
MEDIUM_DEFAULTS = {"color": (1.0, 1.0, 1.0), "depth": 1.0, "scattering": 0.0, "g": 0.9}


def _interface_properties(j: int) -> dict:
    """The dialog's properties of interface ``j`` (1-based): IOR (dielectrics), both roughness controls, rotation."""
    coat = j == 1
    ior = next(p for p in model.INTERFACE["dielectric"] if p.name == "ior")
    return {
        f"ior_{j}": bpy.props.FloatProperty(name="IOR", default=1.49 if coat else 1.5, min=ior.min, max=ior.max,
                                            description=ior.description),
        f"roughness_{j}": bpy.props.FloatProperty(
            name="Roughness", default=0.15 if coat else 0.4, min=0.0, max=1.0, subtype="FACTOR",
            description="As Blender's Glossy BSDF: GGX α = Roughness² (before the anisotropy)"),
        f"anisotropy_{j}": bpy.props.FloatProperty(
            name="Anisotropy", default=0.0 if coat else 0.6, min=-model.GLOSSY_MAX_ANISOTROPY,
            max=model.GLOSSY_MAX_ANISOTROPY, subtype="FACTOR",
            description="As Blender's Glossy BSDF: > 0 stretches the highlight across the interface's tangent, "
                        "< 0 along it"),
        f"alpha_x_{j}": declared(model.ROUGHNESS, "alpha_x", precision=4),
        f"alpha_y_{j}": declared(model.ROUGHNESS, "alpha_y", precision=4),
        f"rotation_{j}": declared(model.ROUGHNESS, "rotation", name="Rotation (°)"),
    }


def _medium_properties(j: int) -> dict:
    """The dialog's properties of the medium below interface ``j`` (1-based)."""
    return {
        f"color_{j}": bpy.props.FloatVectorProperty(
            name="Color", size=3, subtype="COLOR", default=MEDIUM_DEFAULTS["color"], min=0.0, max=1.0,
            description="What is left of light that crosses one unit of depth straight down, exp(-sigma_a) per "
                        "channel: white is clear"),
        f"depth_{j}": declared(model.MEDIUM, "depth", default=MEDIUM_DEFAULTS["depth"]),
        f"scattering_{j}": bpy.props.FloatProperty(
            name="Scattering σs", default=MEDIUM_DEFAULTS["scattering"], min=0.0, soft_max=10.0,
            description="Scattering coefficient per unit depth (grey); 0 is a clear, absorbing medium"),
        f"g_{j}": declared(model.MEDIUM, "g", default=MEDIUM_DEFAULTS["g"]),
    }


def interface_line(j: int, interface) -> str:
    """"1. Dielectric 1.49: α 0.3 × 0.05, rotation 0°" (``j`` 0-based)."""
    ior = "/".join(f"{n:.3g}" for n in sorted(set(interface.ior)))
    if interface.type == "conductor":
        ior = ", ".join(f"{n:.3g}+{k:.3g}i" for n, k in zip(interface.ior, interface.k))
    return (f"{j + 1}. {model.INTERFACE_LABELS[interface.type]} {ior}: α {interface.alpha_x:.3g} × "
            f"{interface.alpha_y:.3g}, rotation {interface.rotation:.0f}°")


def stack_lines(p) -> list[str]:
    """One line per interface, and one per medium of non-zero depth below it."""
    lines = []
    for j, interface in enumerate(p.interfaces):
        lines.append(interface_line(j, interface))
        if j < len(p.media) and p.media[j].depth > 0.0:
            m = p.media[j]
            lines.append(f"   medium: σa·d {', '.join(f'{a * m.depth:.3g}' for a in m.sigma_a)}"
                         + (f", scattering g {m.g:.2f}" if any(m.sigma_s) else ""))
    return lines


class LAMINA_OT_add_aniso_stack(AddMaterialDialog, bpy.types.Operator):
    """Add a new Anisotropic Stack material to the active object: rough interfaces (a clear coat, a brushed metal,
    fibres) each with its own anisotropic roughness and tangent, from a preset or custom"""

    bl_idname = "lamina.add_aniso_stack"
    bl_label = "Add Anisotropic Stack Material"
    dialog_width = 420

    preset: bpy.props.EnumProperty(name="Preset", items=PRESET_ITEMS, default=CUSTOM,
                                   description="A stack after the paper's Figs. 4, 7 and 8 and common finishes, "
                                               "or Custom")
    interfaces: bpy.props.IntProperty(name="Interfaces", default=2, min=1, max=model.MAX_INTERFACES,
                                      description="How many rough interfaces, top first (air above the first)")
    base: bpy.props.EnumProperty(name="Last interface", items=BASE_ITEMS, default="conductor",
                                 description="What the last interface is (only the last may be a metal)")
    metal: bpy.props.EnumProperty(name="Metal", items=METAL_ITEMS, default="aluminium",
                                  description="What the metal is made of")
    metal_ior: declared(model.INTERFACE["conductor"], "ior", name="IOR n", default=METALS["aluminium"][0])
    metal_k: declared(model.INTERFACE["conductor"], "k", name="Extinction k", default=METALS["aluminium"][1])
    roughness_control: bpy.props.EnumProperty(name="Roughness", items=ROUGHNESS_ITEMS, default="glossy",
                                              description="How each interface's anisotropic roughness is set")

    def draw(self, context):
        layout = self.layout
        layout.prop(self, "preset")
        if self.preset != CUSTOM:
            col = layout.column(align=True)
            col.label(text=presets.description(model.ID, self.preset)[:90], icon="INFO")
            for line in stack_lines(model.params_from_dict(self.stack_dict())):
                col.label(text=line)
            col.label(text="Edit the values on the Lamina node afterwards")
        else:
            self._draw_custom(layout.column())
        layout.row().prop(self, "form", expand=True)

    def _draw_custom(self, col) -> None:
        col.prop(self, "interfaces")
        col.row().prop(self, "roughness_control", expand=True)
        for j in range(1, self.interfaces + 1):
            box = col.box()
            last = j == self.interfaces
            box.label(text=f"Interface {j}" + (" (top)" if j == 1 else ""))
            if last:
                box.prop(self, "base")
            if last and self.base == "conductor":
                draw_conductor(box, self, "metal")
            else:
                box.prop(self, f"ior_{j}")
            if self.roughness_control == "glossy":
                box.prop(self, f"roughness_{j}", slider=True)
                box.prop(self, f"anisotropy_{j}", slider=True)
                ax, ay = self.alpha(j)
                box.label(text=f"α {ax:.3g} along the tangent × {ay:.3g} across"
                               + (" (capped at 1)" if max(ax, ay) > 1.0 else ""))
            else:
                box.prop(self, f"alpha_x_{j}", slider=True)
                box.prop(self, f"alpha_y_{j}", slider=True)
            box.prop(self, f"rotation_{j}")
            if not last:
                self._draw_medium(col.box(), j)

    def _draw_medium(self, box, j: int) -> None:
        box.label(text=f"Medium between interfaces {j} and {j + 1}")
        box.prop(self, f"color_{j}")
        box.prop(self, f"depth_{j}")
        box.prop(self, f"scattering_{j}")
        if getattr(self, f"scattering_{j}") > 0.0:
            box.prop(self, f"g_{j}", slider=True)

    def alpha(self, j: int) -> tuple[float, float]:
        """(αx, αy) of interface ``j`` (1-based) from the chosen roughness control."""
        if self.roughness_control == "glossy":
            return model.alpha_from_glossy(getattr(self, f"roughness_{j}"), getattr(self, f"anisotropy_{j}"))
        return getattr(self, f"alpha_x_{j}"), getattr(self, f"alpha_y_{j}")

    def stack_dict(self) -> dict:
        """The Anisotropic Stack dict the dialog describes (a preset's, or the Custom settings)."""
        if self.preset != CUSTOM:
            return presets.load(model.ID, self.preset)
        interfaces = []
        for j in range(1, self.interfaces + 1):
            if j == self.interfaces and self.base == "conductor":
                ior, k = conductor_values(self, "metal")
                interface = {"type": "conductor", "ior": list(ior), "k": list(k)}
            else:
                interface = {"type": "dielectric", "ior": getattr(self, f"ior_{j}")}
            interfaces.append({**interface, "alpha": list(self.alpha(j)), "rotation": getattr(self, f"rotation_{j}")})
        media = [{"sigma_a": sigma_a_from_color(getattr(self, f"color_{j}"), model.MEDIUM),
                  "depth": getattr(self, f"depth_{j}"), "sigma_s": [getattr(self, f"scattering_{j}")] * 3,
                  "g": getattr(self, f"g_{j}")} for j in range(1, self.interfaces)]
        return {"interfaces": interfaces, "media": media}

    def execute(self, context):
        name = f"{model.LABEL} {label(self.preset)}" if self.preset != CUSTOM else model.LABEL
        return add_material(self, context, model.ID, self.stack_dict(), name)


for _j in range(1, model.MAX_INTERFACES + 1):  # numbered properties: one set per interface and per medium
    LAMINA_OT_add_aniso_stack.__annotations__.update(_interface_properties(_j))
    if _j < model.MAX_INTERFACES:
        LAMINA_OT_add_aniso_stack.__annotations__.update(_medium_properties(_j))
del _j

ADD = (LAMINA_OT_add_aniso_stack.bl_idname, "NODE_MATERIAL")  # the panel's Add button: operator and icon
classes = (LAMINA_OT_add_aniso_stack,)

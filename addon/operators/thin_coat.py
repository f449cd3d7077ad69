"""Add Thin Coat Material: a clear or tinted coat, rough on both sides, over a diffuse, metal or dielectric base, or a
free-standing thin sheet; and the texts the dialog and the panel show of a thin coat."""
from __future__ import annotations

import bpy

from .. import presets
from ..models import metals, thin_coat
from ..models.metals import METALS
from .material_ops import (CUSTOM, AddMaterialDialog, add_material, conductor_values, declared, draw_conductor, label,
                           metal_items, preset_items, sigma_a_from_color)

PRESET_ITEMS = preset_items(thin_coat.ID, "Set the interfaces, the coat and the base below")
BASE_ITEMS = [(key, thin_coat.BASE_LABELS[key], description) for key, description in (
    ("diffuse", "A matte (Lambertian) base under the coat: lacquered wood, glazed ceramic, varnished paint"),
    ("conductor", "A metal under the coat: varnished or lacquered metal, car paint's metal base"),
    ("dielectric_rough", "An opaque rough dielectric under the coat (the paper's case): only its Fresnel "
                         "reflection shows; the light it refracts is absorbed"),
    ("slab", "No base: a free-standing thin transparent sheet that reflects and transmits (leaves of glass, "
             "foils, varnish films)"))]
METAL_ITEMS = metal_items(METALS, "A base of")


def kappa_text(kappa: float) -> str:
    """κ as the dialog and the panel show it: "κ 200", "κ 20000", "κ 1e+06"."""
    return f"κ {kappa:.0f}" if kappa < 1e5 else f"κ {kappa:.0e}"


def interface_text(p, side: str) -> str:
    """"roughness α 0.100 (κ 200)" for the top or bottom interface of thin-coat parameters ``p``."""
    return f"roughness α {getattr(p, f'roughness_{side}'):.3g} ({kappa_text(getattr(p, f'kappa_{side}'))})"


class LAMINA_OT_add_thin_coat(AddMaterialDialog, bpy.types.Operator):
    """Add a new Thin Coat material to the active object (a clear or tinted transparent coat, rough on both sides,
    over a diffuse, metal or dielectric base, or a free-standing thin sheet), from a preset or custom"""

    bl_idname = "lamina.add_thin_coat"
    bl_label = "Add Thin Coat Material"
    dialog_width = 380

    preset: bpy.props.EnumProperty(name="Preset", items=PRESET_ITEMS, default=CUSTOM,
                                   description="A coat after the paper's Figs. 16 and 18 and common finishes, "
                                               "or Custom")
    roughness_top: declared((thin_coat.ROUGHNESS["top"],), "roughness_top", soft_max=1.0, precision=3)
    roughness_bottom: declared((thin_coat.ROUGHNESS["bottom"],), "roughness_bottom", soft_max=1.0, precision=3)
    eta: declared(thin_coat.LAYER, "eta")
    coat_color: bpy.props.FloatVectorProperty(
        name="Coat Color", size=3, subtype="COLOR", default=(1.0, 1.0, 1.0), min=0.0, max=1.0,
        description="What is left of light that crosses one unit of depth straight down, exp(-sigma_a) per "
                    "channel: white is a clear coat; a thicker coat (Depth) looks deeper")
    depth: declared(thin_coat.LAYER, "depth")
    base_type: bpy.props.EnumProperty(name="Base", items=BASE_ITEMS, default="diffuse",
                                      description="What is under the coat")
    base_color: declared(thin_coat.BASE["diffuse"], "albedo")
    base_ior: declared(thin_coat.BASE["dielectric_rough"], "ior")
    metal: bpy.props.EnumProperty(name="Metal", items=METAL_ITEMS, default="aluminium",
                                  description="What the metal base is made of")
    metal_ior: declared(thin_coat.BASE["conductor"], "eta", name="IOR n", default=METALS["aluminium"][0])
    metal_k: declared(thin_coat.BASE["conductor"], "k", name="Extinction k", default=METALS["aluminium"][1])
    bounces: declared(thin_coat.STACK, "bounces")
    merge_orders: declared(thin_coat.STACK, "merge_orders")

    def draw(self, context):
        layout = self.layout
        layout.prop(self, "preset")
        if self.preset != CUSTOM:
            self._draw_preset(layout.column(align=True))
        else:
            self._draw_custom(layout.column())
        col = layout.column(align=True)
        col.prop(self, "bounces")
        col.label(text="0: the top interface only (fastest); each bounce adds a lobe,", icon="INFO")
        col.label(text="the first carries most of the energy: 2 is usually enough")
        col.prop(self, "merge_orders")
        layout.row().prop(self, "form", expand=True)
        layout.row().prop(self, "mapping", expand=True)

    def _draw_preset(self, col) -> None:
        """The preset's description and values (edit them on the Lamina node afterwards)."""
        p = thin_coat.params_from_dict(self.coat_dict())
        col.label(text=presets.description(thin_coat.ID, self.preset), icon="INFO")
        col.label(text=f"Top: {interface_text(p, 'top')}")
        if p.base.type != "diffuse":
            col.label(text=f"Bottom: {interface_text(p, 'bottom')}")
        sigma_d = ", ".join(f"{s * p.depth:.2g}" for s in p.sigma_a)
        col.label(text=f"Coat IOR η {p.eta:.2f}; absorption σa·d ({sigma_d})")
        col.label(text=f"Base: {base_text(p)}")
        col.label(text="Edit the values on the Lamina node afterwards")

    def _draw_custom(self, col) -> None:
        col.label(text="Interfaces (roughness α = sqrt(2 / κ))")
        for side in thin_coat.INTERFACES:
            split = col.split(factor=0.78)
            split.enabled = side == "top" or self.base_type != "diffuse"
            split.prop(self, f"roughness_{side}", slider=True)
            split.label(text=kappa_text(thin_coat.kappa_from_roughness(getattr(self, f"roughness_{side}"))))
        if self.base_type == "diffuse":
            col.label(text="The bottom roughness has no effect over a diffuse base")
        col.separator()
        col.prop(self, "eta")
        col.prop(self, "coat_color")
        col.prop(self, "depth")
        tint = ", ".join(f"{c ** (2.0 * self.depth):.2f}" for c in self.coat_color)
        col.label(text=f"Round trip at normal incidence keeps ({tint})")
        col.separator()
        col.prop(self, "base_type")
        if self.base_type == "diffuse":
            col.prop(self, "base_color")
        elif self.base_type == "dielectric_rough":
            col.prop(self, "base_ior")
        elif self.base_type == "conductor":
            draw_conductor(col, self, "metal")

    def coat_dict(self) -> dict:
        """The thin-coat dict the dialog describes (a preset's or the Custom settings) with the dialog's bounces and
        order merging."""
        if self.preset != CUSTOM:
            data = presets.load(thin_coat.ID, self.preset)
        else:
            data = {"roughness_top": self.roughness_top, "roughness_bottom": self.roughness_bottom,
                    "eta": self.eta, "sigma_a": sigma_a_from_color(self.coat_color, thin_coat.LAYER), "depth": self.depth}
            base = {"type": self.base_type}
            if self.base_type == "diffuse":
                base["albedo"] = list(self.base_color)
            elif self.base_type == "dielectric_rough":
                base["ior"] = self.base_ior
            elif self.base_type == "conductor":
                ior, k = conductor_values(self, "metal")
                base["eta"], base["k"] = list(ior), list(k)
            data["base"] = base
        data = {k: v for k, v in data.items() if k not in ("name", "description")}
        return {**data, "bounces": self.bounces, "merge_orders": self.merge_orders}

    def execute(self, context):
        name = f"{thin_coat.LABEL} {label(self.preset)}" if self.preset != CUSTOM else thin_coat.LABEL
        return add_material(self, context, thin_coat.ID, self.coat_dict(), name)


def base_text(p) -> str:
    """The base of thin-coat parameters ``p`` in words, with its values."""
    b = p.base
    kind = thin_coat.BASE_LABELS[b.type]
    if b.type == "diffuse":
        return f"{kind}, colour ({', '.join(f'{c:.2f}' for c in b.albedo)})"
    if b.type == "dielectric_rough":
        return f"{kind}, IOR {b.ior:.2f}"
    if b.type == "conductor":
        named = metals.named(b.eta, b.k)
        return f"{kind}, {named}" if named else f"{kind}, n ({', '.join(f'{c:.2f}' for c in b.eta)})"
    return kind


ADD = (LAMINA_OT_add_thin_coat.bl_idname, "MATSHADERBALL")  # the panel's Add button: operator and icon
classes = (LAMINA_OT_add_thin_coat,)

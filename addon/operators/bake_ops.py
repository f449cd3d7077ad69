"""Bake Textures: the multiple scattering of Lamina layers driven by Image Textures, baked per texel into EXR
maps (``bake.textures``) and wired into the Lamina node's ``MS`` inputs (``nodes.texture_wiring``).

A bake (``BakeRun``) has three phases: prepare (check the material, read and validate every texture, look for
a cached bake of the same content), compute (the network, one chunk of texels per ``step``: the operator steps
from a timer, so the UI stays responsive and Esc cancels between chunks; then, one step more, the energy budget table
that follows the texels, ``nodes.spongecake.TexelEnergy``) and ``finish`` (write the EXRs as one
set, then wire). Nothing is written before the computation is complete and nothing is wired before the files
exist, so a refused, failed or cancelled bake leaves the material and the cache folder as they were.

Cache folder: ``//lamina_cache/`` next to the saved .blend (image paths stored relative to it); for an unsaved
file the extension's user folder (``bpy.utils.extension_path_user``), or the system temp folder when Lamina
runs from a source tree.
"""
from __future__ import annotations

import os
import tempfile

import bpy

from ..bake import textures
from ..bake.textures import BakeError
from ..nodes import material as lamina_material
from ..nodes import spongecake as mapping
from ..nodes import texture_wiring
from . import blend_io
from .progress import end_modal


class MaterialError(BakeError):
    """The material itself cannot be baked: not a Lamina material, its Lamina node is gone, MS is off."""


# How to fix a refused material, in the words of the interface in use (the panel, or the headless command).
PANEL, CLI = "panel", "cli"
FIXES = {
    PANEL: {"no node": "add it again with Add SpongeCake Material",
            "ms off": "turn it on in the Lamina panel first"},
    CLI: {"no node": "write it again with lamina make-material",
          "ms off": 'turn it on in Blender\'s Lamina panel, or write the material with lamina make-material from a '
                    'dict with "multiple_scattering": true'},
}


def check_material(mat, interface: str = PANEL) -> None:
    fix = FIXES[interface]
    if not lamina_material.is_lamina(mat):
        raise MaterialError(f"{mat.name} is not a Lamina material")
    if lamina_material.shader_node(mat) is None:
        raise MaterialError(f"{mat.name} has no Lamina node (edited outside Lamina?); {fix['no node']}")
    if not lamina_material.info(mat)["params"].get("multiple_scattering"):
        raise MaterialError(f"{mat.name} has multiple scattering off: {fix['ms off']}")


def cache_folder() -> str:
    if bpy.data.filepath:
        return bpy.path.abspath("//lamina_cache")
    return blend_io.extension_folder("cache") or os.path.join(tempfile.gettempdir(), "lamina_cache")


class BakeRun:
    """One bake of one material (module docstring). Raises BakeError with a one-line reason when refused."""

    def __init__(self, mat, folder: str | None = None, interface: str = PANEL):
        check_material(mat, interface)
        self.interface = interface
        self.material_name = mat.name
        self.warnings: list[str] = []
        self.sources = texture_wiring.sources(mat)
        _, self.params = lamina_material.current_params(mat)
        self.form = lamina_material.form_of(mat)
        self.folder = folder or cache_folder()
        self.fraction = 0.0
        self.maps = self.paths = self._steps = self.texels = None
        self.cache_hit = False
        if not self.sources:
            return  # nothing to bake: finish() writes the constants
        texture_wiring.vector_source(self.sources)  # refuse textures with different mappings before computing
        self.inputs = texture_wiring.read_inputs(self.sources, self.warnings)
        self.texels = mapping.texel_energy(self.params, textures.input_ranges(self.params, self.inputs))
        self.key = textures.cache_key(self.params, self.inputs)
        self.paths = textures.cached_maps(self.params, self.folder, self.key)
        self.cache_hit = self.paths is not None
        labels = {s.key: s.label for s in self.sources}
        maps = None if self.cache_hit else textures.bake_steps(self.params, self.inputs, labels, self.warnings)
        self._steps = self._with_energy_table(maps)

    def _with_energy_table(self, maps):
        """The maps' steps (none for a cache hit), then one more that computes the energy budget table that follows
        the texels (``nodes.spongecake.TexelEnergy``: seconds, cached for ``finish``)."""
        result = (yield from maps) if maps is not None else None
        yield 1.0
        mapping.budget_table(self.params, self.form, self.texels)
        return result

    def step(self) -> bool:
        """Compute the next chunk of texels (the first step validates them); False when nothing is left."""
        if self._steps is None:
            return False
        try:
            self.fraction = next(self._steps)
            return True
        except StopIteration as done:
            self.maps, self._steps = done.value, None
            return False

    def cancel(self) -> None:
        if self._steps is not None:
            self._steps.close()
            self._steps = None

    def finish(self) -> str:
        """Write the maps (unless cached) and wire them; returns a one-line summary."""
        mat = bpy.data.materials.get(self.material_name)
        if mat is None:
            raise BakeError(f"{self.material_name} was removed while baking")
        check_material(mat, self.interface)
        if lamina_material.current_params(mat)[1] != self.params:
            raise BakeError(f"{mat.name} changed while baking; bake again")
        if not self.sources:
            texture_wiring.unwire(mat)
            lamina_material.set_texel_energy(mat, None)
            lamina_material.bake_constants(mat)
            return (f"No Image Texture drives a layer input of {mat.name}: nothing to bake; it uses the constant "
                    f"multiple-scattering values")
        if self.paths is None:
            self.paths = textures.write_maps(self.maps, self.folder, self.key)
        texture_wiring.wire(mat, textures.map_layout(self.params), self.paths, self.sources)
        lamina_material.set_texel_energy(mat, self.texels)
        lamina_material.bake_constants(mat)  # records the bake; every MS input is linked now
        h, w = next(iter(self.inputs.values())).shape[:2]
        return (f"Baked the multiple scattering of {mat.name} at {w} x {h} into {len(self.paths)} maps in "
                f"{self.folder}" + (" (cache hit: nothing recomputed)" if self.cache_hit else ""))


def bake(mat, folder: str | None = None, interface: str = PANEL) -> tuple[str, list[str]]:
    """Bake ``mat`` synchronously: (summary, warnings); refusals worded for ``interface``."""
    run = BakeRun(mat, folder, interface)
    while run.step():
        pass
    return run.finish(), run.warnings


def bake_file(blend: str, material: str, out: str) -> tuple[str, list[str]]:
    """Open ``blend``, bake ``material`` (textures, or constants when no texture drives it) and save the file as
    ``out`` atomically; nothing is saved when the bake is refused. A file Blender cannot read or a material it
    does not have raise ``blend_io.BlendArgumentError``."""
    blend_io.open_blend(blend)
    summary, warnings = bake(blend_io.find_material(material, blend), interface=CLI)
    blend_io.save_copy(out)
    return summary, warnings


class LAMINA_OT_bake_textures(bpy.types.Operator):
    """Bake the multiple scattering of layers driven by Image Textures into EXR textures and wire them into the
    Lamina node (Esc cancels; nothing is changed until the bake is complete)"""

    bl_idname = "lamina.bake_textures"
    bl_label = "Bake Textures"
    bl_options = {"REGISTER", "UNDO"}

    _timer = None
    _run = None

    @classmethod
    def poll(cls, context):
        return lamina_material.is_lamina(getattr(context, "material", None))

    def _start(self, context) -> bool:
        try:
            self._run = BakeRun(context.material)
        except BakeError as e:
            self.report({"ERROR"}, str(e))
            return False
        return True

    def execute(self, context):  # scripted and headless use: every step at once
        if not self._start(context):
            return {"CANCELLED"}
        return self._finish()

    def invoke(self, context, event):
        if not self._start(context):
            return {"CANCELLED"}
        wm = context.window_manager
        wm.progress_begin(0, 100)
        self._timer = wm.event_timer_add(0.01, window=context.window)
        wm.modal_handler_add(self)
        return {"RUNNING_MODAL"}

    def modal(self, context, event):
        if event.type == "ESC":
            self._run.cancel()
            self._cleanup(context)
            self.report({"WARNING"}, "Bake cancelled: nothing was written or changed")
            return {"CANCELLED"}
        if event.type != "TIMER":
            return {"PASS_THROUGH"}
        try:
            more = self._run.step()
        except BakeError as e:
            self._cleanup(context)
            self.report({"ERROR"}, str(e))
            return {"CANCELLED"}
        if more:
            context.window_manager.progress_update(int(100 * self._run.fraction))
            if context.workspace is not None:
                context.workspace.status_text_set(f"Lamina: baking {self._run.material_name} "
                                                  f"{self._run.fraction:.0%} (Esc cancels)")
            return {"RUNNING_MODAL"}
        self._cleanup(context)
        return self._finish()

    def _finish(self):
        """Compute what is left (everything, for ``execute``), then write and wire."""
        try:
            while self._run.step():
                pass
            summary = self._run.finish()
        except BakeError as e:
            self.report({"ERROR"}, str(e))
            return {"CANCELLED"}
        except (OSError, ReferenceError) as e:  # a full disk, a node deleted while baking: nothing was wired
            self.report({"ERROR"}, f"Could not bake {self._run.material_name}: {e}")
            return {"CANCELLED"}
        for w in self._run.warnings:
            self.report({"WARNING"}, w)
        self.report({"INFO"}, summary)
        return {"FINISHED"}

    def _cleanup(self, context):
        end_modal(context, self._timer)
        self._timer = None

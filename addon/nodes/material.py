"""Assemble Lamina materials from a model's mapping: node-group form and OSL form, switchable.

Node groups and OSL texts are named with a ``Lamina`` prefix and reused per content hash, so re-running an
operator never duplicates them. Parameter values live on the group or script node's inputs; the model dict
is kept in the material's ``lamina`` property so the other form can be generated from the current values.
With multiple scattering, the network's prediction is baked into the node's ``MS`` inputs and the material's
``lamina_ms_key`` property records which parameters (and networks) it was baked for; inputs that the mapping feeds
from a table over the view (``view_inputs``) get a packed image looked up at the view (``view_wiring``). Switching
form, mapping or multiple scattering replaces only Lamina's own nodes; the user's nodes and links around them stay,
and keys and drivers on the Lamina node's inputs move to the new node (``_replace``). The mapping (analytic, fitted, Auto;
``choice``) is chosen at each rebuild and recorded in ``lamina_fit`` with the fit it renders; an input fed by an
Image Texture or by keyframes is tabulated over its range (``plan``), other linked or animated inputs fall back to
the analytic mapping with a note.
"""
from __future__ import annotations

import hashlib
import importlib
import json
import math
from dataclasses import dataclass, replace

import bpy
import numpy as np

from ..bake.textures import BakeError
from ..models import MODELS
from ..models.micrograin import WRAPPED, Bulk
from . import (FORMS, MAPPING_KINDS, MAPPINGS, choice, fittable, fitted, image_values, input_values, osl, pruning,
               shade, view_inputs, view_wiring)
from .expr import BULK_INPUT, TANGENT_INPUT, NumpyBackend, OslBackend
from .node_backend import GENERATOR_VERSION, NodeBackend

GENERATOR_KEY = "lamina_generator"  # the GENERATOR_VERSION that built a material's Lamina node
# What the numpy prediction (and so a fit) assumes of node groups follows the running Blender: 4.2 has no Metallic
# BSDF node.
NumpyBackend.metallic_node = NodeBackend.has_metal()
SOCKET_TYPES = {"float": "NodeSocketFloat", "color": "NodeSocketColor", "vector": "NodeSocketVector",
                "shader": "NodeSocketShader"}


def content_hash(model_id: str, p, fit=None) -> str:
    """The structure's hash; a fitted mapping's tables are part of the shader (``fitted.Fit.digest``)."""
    key = repr((GENERATOR_VERSION, model_id, MAPPINGS[model_id].structure_key(p), fit and fit.digest()))
    return hashlib.md5(key.encode()).hexdigest()[:8]


def _label(model_id: str) -> str:
    return (MODELS[model_id] if model_id in MODELS else MAPPINGS[model_id]).LABEL


def _base_name(model_id: str, p, fit=None) -> str:
    return f"Lamina {_label(model_id)}{' ' + fit.LABEL if fit else ''} {content_hash(model_id, p, fit)}"


# ------------------------------------------------------------------------------------------ node group


def node_group(model_id: str, p, fit=None) -> bpy.types.NodeTree:
    """The node group for this structure (and fitted tables), created once and reused."""
    name = _base_name(model_id, p, fit)
    group = bpy.data.node_groups.get(name)
    if group is not None and group.get("lamina_hash") == content_hash(model_id, p, fit):
        return group
    group = bpy.data.node_groups.new(name, "ShaderNodeTree")
    group["lamina_hash"] = content_hash(model_id, p, fit)
    _make_interface(group, MAPPINGS[model_id].sockets(p))
    group_in = group.nodes.new("NodeGroupInput")
    group_out = group.nodes.new("NodeGroupOutput")
    group_in.location = (-250, 0)
    backend = NodeBackend(group, group_in, group_out)
    shade(backend, model_id, p, fit)
    backend.finish()
    return group


def _make_interface(group, sockets) -> None:
    panels = {}
    for s in sockets:
        if s.panel not in panels:
            panels[s.panel] = group.interface.new_panel(s.panel)
        item = group.interface.new_socket(s.name, in_out="INPUT", socket_type=SOCKET_TYPES[s.kind],
                                          parent=panels[s.panel], description=s.param.description)
        if s.kind == "shader":
            continue
        item.default_value = _socket_value(s.param.default, item.default_value)
        if s.kind == "float":
            item.min_value = s.param.min if s.param.min is not None else -1e9
            item.max_value = s.param.max if s.param.max is not None else 1e9
        elif s.kind == "vector":
            item.min_value, item.max_value = -1.0, 1.0
    group.interface.new_socket("BSDF", in_out="OUTPUT", socket_type="NodeSocketShader")


def _socket_value(value, current):
    if not hasattr(current, "__len__"):
        return float(value)
    return (tuple(value) + (1.0,))[: len(current)]


# ------------------------------------------------------------------------------------------------ OSL


def osl_source(model_id: str, p, fit=None) -> str:
    mapping = MAPPINGS[model_id]
    backend = OslBackend([(s.name, s.kind, s.param.default) for s in mapping.sockets(p)])
    shade(backend, model_id, p, fit)
    header = (f"// {_base_name(model_id, p, fit)}: generated by Lamina (generator {GENERATOR_VERSION}); "
              f"see docs/accuracy.md for the approximations")
    return backend.source(f"lamina_{model_id}", header)


def osl_text(model_id: str, p, fit=None) -> bpy.types.Text:
    """The generated source kept as a Text datablock so an artist can read it."""
    name = _base_name(model_id, p, fit) + ".osl"
    text = bpy.data.texts.get(name) or bpy.data.texts.new(name)
    source = osl_source(model_id, p, fit)
    if text.as_string() != source:
        text.from_string(source)
    return text


# ------------------------------------------------------------------------------------------- material


def empty_material(name: str):
    """A new material whose node tree holds only a Material Output: (material, tree, output node)."""
    mat = bpy.data.materials.new(name)
    if bpy.app.version < (5, 0, 0):
        mat.use_nodes = True
    _clear(mat.node_tree)
    return mat, mat.node_tree, mat.node_tree.nodes["Material Output"]


def _clear(tree):
    tree.nodes.clear()
    out = tree.nodes.new("ShaderNodeOutputMaterial")
    out.name = "Material Output"
    out.location = (300, 0)


def new_material(model_id: str, p, form: str = "nodes", name: str | None = None,
                 mapping: str = "analytic") -> bpy.types.Material:
    """A new material (never an existing one overwritten) showing ``p`` in the chosen form and mapping
    (``MAPPING_KINDS``; the operators and the CLI default to Auto, this function to the analytic mapping, which
    measures nothing)."""
    if form not in FORMS:
        raise ValueError(f"unknown form {form!r}; expected one of {', '.join(FORMS)}")
    if mapping not in MAPPING_KINDS:
        raise ValueError(f"unknown mapping {mapping!r}; expected one of {', '.join(MAPPING_KINDS)}")
    mat, _, _ = empty_material(name or MODELS[model_id].LABEL)
    _rebuild(mat, model_id, p, form, mapping)
    return mat


def principled_material(model_id: str, p, name: str = "Lamina Principled") -> bpy.types.Material:
    """A new material: a Principled BSDF set up by the model's mapping for ``p`` (``principled_settings``: the thin
    coat's Principled coat, the others' Principled of about the same lobe count) into a Material Output."""
    mat, tree, out = empty_material(name)
    bsdf = principled_node(tree, MAPPINGS[model_id].principled_settings(p))
    tree.links.new(bsdf.outputs["BSDF"], out.inputs["Surface"])
    return mat


def principled_node(tree, settings: dict):
    """A new Principled BSDF node in ``tree`` with ``settings`` (socket name -> value) on its inputs."""
    bsdf = tree.nodes.new("ShaderNodeBsdfPrincipled")
    bsdf.location = (-300, 0)
    for socket, value in settings.items():
        bsdf.inputs[socket].default_value = _socket_value(value, bsdf.inputs[socket].default_value)
    return bsdf


def is_lamina(mat) -> bool:
    return mat is not None and "lamina" in mat.keys()


def info(mat) -> dict:
    return json.loads(mat["lamina"])


def current_params(mat):
    """The material's parameters as they are now: the stored dict updated with the shader node's inputs. Under a
    porous layer, the reference bulk's values come from the node ``Lamina Bulk``; when that node no longer feeds
    the layer's Bulk input (the user plugged their own shader in), the bulk is the wrapped shader."""
    data = info(mat)
    model_id = data["model"]
    p = MODELS[model_id].params_from_dict(data["params"])
    node = shader_node(mat)
    if node is None:
        return model_id, p
    p = _read_params(node, model_id, p)
    if _has_reference_bulk(model_id, p):
        bulk = _bulk_node(node)
        if bulk is None:
            return model_id, replace(p, bulk=Bulk(WRAPPED, None))
        bulk_id, params = MAPPINGS[model_id].bulk_shader(p)
        p = replace(p, bulk=replace(p.bulk, params=_read_params(bulk, bulk_id, params)))
    return model_id, p


def _bulk_node(layer):
    """The node ``Lamina Bulk`` when it feeds ``layer``'s Bulk input, else None."""
    socket = layer.inputs.get(BULK_INPUT)
    if socket is None or not socket.is_linked or socket.links[0].from_node.name != BULK_NODE:
        return None
    return socket.links[0].from_node


def _read_params(node, mapping_id: str, p):
    mapping = MAPPINGS[mapping_id]
    values = {s.name: _read_socket(node, s) for s in mapping.sockets(p) if not s.baked and s.kind != "shader"}
    return mapping.with_values(p, values)


def form_of(mat) -> str:
    node = shader_node(mat)
    return "osl" if node is not None and node.bl_idname == "ShaderNodeScript" else "nodes"


def set_form(mat, form: str) -> None:
    """Rebuild the material's Lamina node in ``form``, keeping the current parameter values and mapping."""
    model_id, p = current_params(mat)
    _rebuild(mat, model_id, p, form, mapping_of(mat))


def set_mapping(mat, mapping: str) -> None:
    """Rebuild the material's Lamina node with ``mapping`` (``MAPPING_KINDS``), keeping the values and the form;
    also refits a stale fit."""
    if mapping not in MAPPING_KINDS:
        raise ValueError(f"unknown mapping {mapping!r}; expected one of {', '.join(MAPPING_KINDS)}")
    model_id, p = current_params(mat)
    _rebuild(mat, model_id, p, form_of(mat), mapping)


def mapping_of(mat) -> str:
    """The mapping the user chose (materials made before the choice existed: analytic)."""
    return info(mat).get("mapping", "analytic")


DEFERRED_NOTE = "the stack changed: Refit to fit it again"
FIT_RECORD = "lamina_fit"  # the choice's record: {"used", "key", "error"[, "fit"]} (the panel reads it)


def fit_record(mat) -> dict | None:
    return json.loads(mat[FIT_RECORD]) if FIT_RECORD in mat.keys() else None


def fit_of(mat):
    """The fitted tables the material renders with (``fitted.Fit``), or None for the analytic mapping."""
    record = fit_record(mat)
    return fitted.Fit.from_arrays(record["fit"]) if record and "fit" in record else None


def fit_is_stale(mat) -> bool:
    """Whether the values changed since the mapping was fitted and chosen (a fitted table belongs to the values it
    was fitted for), inputs of a fitted material became linked or animated (``driven_inputs``), or what feeds the
    input a driven fit follows changed: another image (or its size), or the keyframes' range (a texture's pixels are
    not compared: edit, then Refit)."""
    record = fit_record(mat)
    if record is None or shader_node(mat) is None:
        return False
    model_id, p = current_params(mat)
    driven = fitted.Driven.from_json(record["driven"]) if "driven" in record else None
    if driven is not None:
        if _fit_inputs(mat, model_id, p) != [driven.socket] or _source(mat, driven.socket) != record["source"]:
            return True
    elif record["used"] == "fitted" and _fit_inputs(mat, model_id, p):
        return True
    return record["key"] != choice.fit_key(model_id, p, form_of(mat), driven)


def driven_inputs(mat) -> list[str]:
    """The Lamina node's inputs whose value is not the socket's constant: linked (a texture, other nodes; a muted link
    leaves the constant) or animated / driven. A fit holds for constant values only, or follows one texture or
    keyframed input (``plan``)."""
    node = shader_node(mat)
    if node is None:
        return []
    names = {s.name for s in node.inputs
             if image_values.linked_from(s) is not None and s.name not in (BULK_INPUT, TANGENT_INPUT)}
    names |= {name for _, name, _ in _input_curves(mat.node_tree, node)}
    return sorted(names)


@dataclass(frozen=True)
class Plan:
    """What a rebuild asks ``choice.choose`` for: the ``mapping``, the ``driven`` input it tabulates and the
    ``source`` feeding it (``_source``: staleness), or, where inputs are driven in a way no fit follows, the
    analytic mapping and a ``note`` saying why."""
    mapping: str
    driven: fitted.Driven | None = None
    source: list | None = None
    note: str = ""


def plan(mat, model_id: str, p, mapping: str) -> Plan:
    """The ``Plan`` for giving ``mat`` (its current parameters ``p``) the ``mapping``: one float or colour input fed
    by an Image Texture (its range read from the pixels, as Cycles sees them) or by keyframes (their range,
    ``_keyframed``) is tabulated; anything else that is linked or animated renders analytic, with a note."""
    if mapping == "analytic" or not fittable(model_id) or not _fit_inputs(mat, model_id, p):
        return Plan(mapping)
    try:
        driven = _followed_input(mat, model_id, p)
    except BakeError as e:
        return Plan("analytic", note=f"{e}; the analytic mapping renders")
    source = _source(mat, driven.socket)
    middle = driven.values[len(driven.values) // 2]
    note = (f"{driven.socket} follows its {'texture' if source[0] == 'image' else 'keyframes'}: fitted at "
            f"{len(driven.values)} values from {driven.values[0]:.3g} to {driven.values[-1]:.3g}; errors measured at "
            f"{middle:.3g}")
    return Plan(mapping, driven, source, note)


def _fit_inputs(mat, model_id: str, p) -> list[str]:
    """``driven_inputs`` less the ``MS`` inputs that baked maps feed (they follow the textures of the layers)."""
    baked = {_norm(s.name) for s in MAPPINGS[model_id].sockets(p) if s.baked}
    return [_name(model_id, p, n) for n in driven_inputs(mat) if _norm(n) not in baked]


def _name(model_id: str, p, key: str) -> str:
    """A shader input's name from its socket name (a script node's is an identifier)."""
    return next((s.name for s in MAPPINGS[model_id].sockets(p) if _norm(s.name) == _norm(key)), key)


def _followed_input(mat, model_id: str, p) -> fitted.Driven:
    """The one input a fit can follow, tabulated over its range; BakeError saying why there is none."""
    names = _fit_inputs(mat, model_id, p)
    if len(names) > 1:
        raise BakeError(f"{', '.join(names)}: linked or animated; a fit follows one input (a texture or keyframes)")
    socket = next((s for s in MAPPINGS[model_id].sockets(p) if s.name == names[0]), None)
    if socket is None or socket.kind not in ("float", "color"):
        raise BakeError(f"{names[0]}: a fit follows float and colour inputs, not {socket.kind if socket else 'this'}")
    values = _input_values(mat, socket)
    if not np.isfinite(values).all():
        raise BakeError(f"{socket.name}: NaN or infinite values (texels or keys)")
    return choice.driven_over(model_id, p, socket.name, float(values.min()), float(values.max()))


def _input_values(mat, socket) -> np.ndarray:
    """Every value the input ``socket`` takes: its texture's texels, or its keyframed value at each frame of every
    scene; BakeError for anything else."""
    node = shader_node(mat)
    key = socket_key(node, socket.name)
    output = image_values.linked_from(node.inputs[key])
    curves = _curves(mat, socket.name)
    if curves and output is None:
        if any(c.driver is not None for c in curves):
            raise BakeError(f"{socket.name}: a driver sets it; a fit follows keyframes or one texture")
        return _keyframed(node.inputs[key], curves)
    if output is None or output.node.bl_idname != "ShaderNodeTexImage":
        source = f"a {output.node.bl_label}" if output is not None else "no"
        raise BakeError(f"{socket.name}: fed by {source} node; a fit follows an Image Texture linked directly")
    return image_values.read_output(output.node, output.name, socket.kind, f"{output.node.name} ({socket.name})")


def _curves(mat, name: str) -> list:
    node = shader_node(mat)
    return [c for c, n, _ in _input_curves(mat.node_tree, node) if _norm(n) == _norm(name)]


KEY_SAMPLES = 16  # values sampled between two keys (a Bézier segment overshoots its keys)


def _keyframed(socket, curves) -> np.ndarray:
    """The input's value (a colour's three channels) at every key, between keys and at each scene's first and last
    frame: the range it takes (sampled, so that a long frame range costs nothing; the panel asks on every redraw)."""
    keys = sorted({float(k.co[0]) for c in curves for k in c.keyframe_points})
    frames = {float(f) for scene in bpy.data.scenes for f in (scene.frame_start, scene.frame_end)}
    frames |= {float(f) for a, b in zip(keys, keys[1:]) for f in np.linspace(a, b, KEY_SAMPLES + 1)} | set(keys)
    by_channel = {c.array_index: c for c in curves}
    constant = np.atleast_1d(np.asarray(socket.default_value, dtype=np.float64))[:3]
    return np.array([[by_channel[i].evaluate(f) if i in by_channel else constant[i] for i in range(len(constant))]
                     for f in sorted(frames)])


def _source(mat, name: str) -> list | None:
    """What feeds the input ``name``, for staleness: ["image", name, file path, size], ["keyframes", least, greatest]
    (``_keyframed``), or None."""
    curves = _curves(mat, name)
    node = shader_node(mat)
    output = image_values.linked_from(node.inputs[socket_key(node, name)])
    if curves and output is None and all(c.driver is None for c in curves):
        values = _keyframed(node.inputs[socket_key(node, name)], curves)
        return ["keyframes", round(float(values.min()), 6), round(float(values.max()), 6)]
    image = getattr(output.node, "image", None) if output is not None else None
    return None if image is None else ["image", image.name, image.filepath, list(image.size)]


def _input_curves(tree, node) -> list[tuple]:
    """(F-curve or driver, input name, the rest of its data path) of each animated input of ``node``."""
    animation = tree.animation_data
    if animation is None:
        return []
    prefix = f'nodes["{node.name}"].inputs['
    out = []
    for curve in list(animation.drivers) + _fcurves(animation.action):
        if curve.data_path.startswith(prefix):
            index, _, rest = curve.data_path[len(prefix):].partition("]")
            out.append((curve, node.inputs[int(index)].name if index.isdigit() else index.strip('"'), rest))
    return out


def _move_animation(tree, old, node) -> None:
    """Point the F-curves and drivers of ``old``'s inputs at ``node``'s inputs of the same name (``node`` still has its
    own name; renaming it later carries them along), so that removing ``old`` does not delete the user's keys."""
    by_name = {_norm(socket.name): j for j, socket in enumerate(node.inputs)}
    for curve, name, rest in _input_curves(tree, old):
        if _norm(name) in by_name:
            curve.data_path = f'nodes["{node.name}"].inputs[{by_name[_norm(name)]}]{rest}'


def _fcurves(action) -> list:
    """An action's F-curves: Blender 4.2's ``action.fcurves``, or 4.4+'s layered channel bags."""
    if action is None:
        return []
    if hasattr(action, "layers") and len(action.layers):
        return [c for layer in action.layers for strip in layer.strips for bag in getattr(strip, "channelbags", [])
                for c in bag.fcurves]
    return list(getattr(action, "fcurves", []))


def set_multiple_scattering(mat, on: bool) -> None:
    """Rebuild the material's Lamina node with multiple scattering on or off, keeping the current parameter
    values, the form and the user's mapping choice (a fitted or Auto material renders analytic until Refit: the
    toggle does not wait for a fit)."""
    model_id, p = current_params(mat)
    p = MODELS[model_id].validate({**p.to_dict(), "multiple_scattering": on}).params
    _rebuild(mat, model_id, p, form_of(mat), mapping_of(mat), refit=False)


def insert_layer(mat, model_id: str, p, form: str, surface) -> None:
    """Put a new Lamina node for the porous layer ``p`` between a Material Output and the shader linked into its
    ``surface`` input: that shader feeds the node's Bulk input, the node the output, which moves right to make
    room. The nodes are built first (nothing is touched if that fails). When ``p`` has a reference bulk, the shader
    that fed the output must be the node ``Lamina Bulk`` (another Lamina material's node, renamed): it is rebuilt in
    ``form`` like ``set_form`` does. Records the parameters like ``_rebuild``. The material must have no node named
    ``Lamina``."""
    tree = mat.node_tree
    node, bulk = _new_nodes(mat, model_id, p, form)
    out = surface.node
    node.parent = out.parent
    node.location = out.location
    out.location = (out.location.x + node.width + 60.0, out.location.y)
    tree.links.new(surface.links[0].from_socket, node.inputs[BULK_INPUT])
    tree.links.new(node.outputs["BSDF"], surface)
    _replace(mat, None, node)
    _place_bulk(mat, bulk)
    mat["lamina"] = json.dumps({"model": model_id, "params": p.to_dict()})
    bake_constants(mat)


def _rebuild(mat, model_id: str, p, form: str, mapping: str = "analytic", refit: bool = True,
             pruned: pruning.Pruned | None = None) -> None:
    """Choose the mapping (``plan``) and build the tree first (nothing is touched if that fails), then record the
    parameters, the choice and the bake. Without ``refit`` (a toggle that must not wait seconds for a fit), a fitted
    or Auto material keeps the user's choice but renders analytic until Refit (its record is stale). ``pruned``
    (analytic mapping only): the closures left out (Fit to budget); any other rebuild builds them all again."""
    deferred = not refit and mapping != "analytic" and fittable(model_id)
    asked = Plan("analytic", note=DEFERRED_NOTE) if deferred else plan(mat, model_id, p, mapping)
    chosen = choice.choose(model_id, p, form, asked.mapping, asked.driven)
    if pruned is not None and chosen.fit is not None:
        raise ValueError("closures are left out of the analytic mapping only")
    _build_tree(mat, model_id, p, form, pruned or chosen.fit)
    mat["lamina"] = json.dumps({"model": model_id, "params": p.to_dict(), "mapping": mapping,
                                **({"pruned": pruned.to_json()} if pruned else {})})
    if chosen.error or asked.note:
        held = current_params(mat)[1]  # the key of the values as the sockets hold them (float32), as bake_constants
        key = "" if deferred else choice.fit_key(model_id, held, form, asked.driven)  # "": stale, Refit
        record = {"used": chosen.used, "key": key, "error": chosen.error}
        if asked.note:
            record["note"] = asked.note
        if asked.driven is not None:
            record.update(driven=asked.driven.to_json(), source=asked.source)
        mat[FIT_RECORD] = json.dumps(record if chosen.fit is None else {**record, "fit": chosen.fit.to_json()})
    else:
        mat.pop(FIT_RECORD, None)
    bake_constants(mat)  # records the bake key of the values as the sockets hold them (float32)


BUDGET_RECORD = "lamina_budget"  # the last Fit to budget's decision (``budget.Decision.to_json``; the panel reads it)


def budget_record(mat) -> dict | None:
    return json.loads(mat[BUDGET_RECORD]) if BUDGET_RECORD in mat.keys() else None


def used_mapping(mat) -> str:
    """The mapping the material renders with ("analytic" or "fitted"; Auto is one of the two)."""
    record = fit_record(mat)
    return record["used"] if record else "analytic"


def pruned_of(mat) -> pruning.Pruned | None:
    """The closures the material's Lamina node leaves out (Fit to budget), or None."""
    data = info(mat).get("pruned")
    return pruning.Pruned.from_json(data) if data else None


def apply_decision(mat, decision) -> None:
    """Rebuild the Lamina node in the configuration ``decision`` chose (``budget.Decision``: the variant's values,
    form, mapping and the closures left out; the user's other nodes are untouched) and record the decision."""
    chosen = decision.chosen
    _rebuild(mat, info(mat)["model"], chosen.params, chosen.form, chosen.mapping, pruned=chosen.pruned)
    mat[BUDGET_RECORD] = json.dumps(decision.to_json())


# --------------------------------------------------------------------------------- multiple scattering

MS_KEY = "lamina_ms_key"
_ms_shares: dict[tuple[str, str], float] = {}


def ms_key(model_id: str, p) -> str:
    """Identifies a multiple-scattering bake: the parameters, what their multiple scattering comes from (the bake
    module's ``ms_identity``: network and ``MS_VERSION``) and the generator whose shader the baked energy scale fits
    (``GENERATOR_VERSION``)."""
    bake = importlib.import_module(f"..bake.{model_id}", __package__)
    text = json.dumps([p.to_dict(), *bake.ms_identity(len(p.layers)), GENERATOR_VERSION], sort_keys=True)
    return hashlib.md5(text.encode()).hexdigest()


def bake_constants(mat) -> bool:
    """Write the network's prediction for the current parameters into the Lamina node's ``MS`` inputs (linked
    ones, e.g. driven by baked textures, are left alone) and record the bake key. Returns whether anything
    changed; a material without multiple scattering only loses its bake key. A Lamina node made by another generator
    (an earlier Lamina: its inputs or its closures may differ from what the values are computed for) is rebuilt
    first, keeping the form and the mapping choice."""
    model_id, p = current_params(mat)
    node = shader_node(mat)
    if not getattr(p, "multiple_scattering", False) or node is None:
        unwired = node is not None and _wire_view_inputs(mat, node, {})
        return mat.pop(MS_KEY, None) is not None or unwired
    values = MAPPINGS[model_id].ms_values(p, form_of(mat))
    missing = any(socket_key(node, name) not in node.inputs for name in values)
    if missing or mat.get(GENERATOR_KEY) != GENERATOR_VERSION:
        _rebuild(mat, model_id, p, form_of(mat), mapping_of(mat), refit=False)
        return True
    changed = _write_values(node, values)
    changed = _wire_view_inputs(mat, node, view_inputs(model_id, p, form_of(mat), texel_energy(mat))) or changed
    key = ms_key(model_id, p)
    if mat.get(MS_KEY) != key:
        mat[MS_KEY], changed = key, True
    return changed


TEXEL_ENERGY_KEY = "lamina_texel_energy"  # how the energy budget follows the texels (``TexelEnergy``), set by a bake


def set_texel_energy(mat, texels) -> None:
    """Record how the material's view tables follow its texels (a ``TexelEnergy`` from its texture bake; None: it has
    no texture-driven layer)."""
    if texels is None:
        mat.pop(TEXEL_ENERGY_KEY, None)
    else:
        mat[TEXEL_ENERGY_KEY] = json.dumps(texels.to_json())


def texel_energy(mat):
    """The recorded ``TexelEnergy`` of ``mat``, or None: none recorded, or its axis follows an input that is no
    longer there or no longer linked (the material's own table then, until the next bake). A material whose baked
    inputs are fed by texture maps without a record (baked by an earlier Lamina) gets no axis: one table without the
    energy fraction, so that each texel keeps its lobes' own energy until it is baked again."""
    model_id, p = current_params(mat)
    node = shader_node(mat)
    if node is None or not hasattr(MAPPINGS[model_id], "TexelEnergy"):
        return None
    if TEXEL_ENERGY_KEY not in mat.keys():
        return MAPPINGS[model_id].TexelEnergy() if _fed_by_maps(node, model_id, p) else None
    texels = MAPPINGS[model_id].TexelEnergy.from_json(json.loads(mat[TEXEL_ENERGY_KEY]))
    if texels.axis is not None:
        key = socket_key(node, texels.axis.socket)
        if key not in node.inputs or image_values.linked_from(node.inputs[key]) is None:
            return None
    return texels


def _fed_by_maps(node, model_id: str, p) -> bool:
    """Whether a baked input of ``node`` is linked from something other than a view lookup (a texture bake's map)."""
    for s in MAPPINGS[model_id].sockets(p):
        socket = node.inputs.get(socket_key(node, s.name)) if s.baked else None
        if socket is not None and socket.is_linked and not view_wiring.fed(socket):
            return True
    return False


def _wire_view_inputs(mat, node, tables: dict) -> bool:
    """Feed the node's inputs named in ``tables`` from their view tables (``view_wiring``; a table's axis from what
    feeds the input it follows), remove Lamina's lookups that feed nothing any more (with their images); whether any
    link changed."""
    before = {(link.from_node.name, link.to_socket.identifier) for s in node.inputs for link in s.links}

    def follows(table):
        return node.inputs[socket_key(node, table.axis.socket)] if table.axis else None

    idle = view_wiring.wire(node, [(node.inputs[socket_key(node, name)], t, follows(t)) for name, t in tables.items()])
    remove_nodes(mat, idle)
    return before != {(link.from_node.name, link.to_socket.identifier) for s in node.inputs for link in s.links}


def ms_enabled(mat) -> bool:
    """Whether a Lamina material has multiple scattering on (reads the stored flag only: cheap)."""
    return is_lamina(mat) and bool(info(mat)["params"].get("multiple_scattering"))


def ms_is_stale(mat) -> bool:
    """Whether the parameters changed since the multiple-scattering inputs were last baked."""
    model_id, p = current_params(mat)
    if not getattr(p, "multiple_scattering", False) or shader_node(mat) is None:
        return False
    return mat.get(MS_KEY) != ms_key(model_id, p)


def ms_energy_share(mat) -> float:
    """The multiple-scattering closures' share of the energy the material sends back and through for light along
    the normal as Cycles renders it (white furnace, mean over RGB; the mapping's ``ms_share``, numpy prediction),
    cached per bake key. Raises ParamError for stacks no network covers."""
    model_id, p = current_params(mat)
    p = MODELS[model_id].validate({**p.to_dict(), "multiple_scattering": True}).params
    key = ms_key(model_id, p), form_of(mat)
    if key not in _ms_shares:
        _ms_shares[key] = MAPPINGS[model_id].ms_share(p, key[1])
    return _ms_shares[key]


def shader_node(mat):
    return mat.node_tree.nodes.get("Lamina") if mat.node_tree else None


def _build_tree(mat, model_id: str, p, form: str, fit=None) -> None:
    """Put the Lamina node in ``form`` into the material, replacing only Lamina's own nodes (``_replace``);
    nothing is touched if generation fails (the nodes are built first: groups built, OSL compiled). A porous
    layer's reference bulk gets a Lamina node of its own, ``Lamina Bulk``."""
    node, bulk = _new_nodes(mat, model_id, p, form, fit)
    _replace(mat, shader_node(mat), node)
    _place_bulk(mat, bulk)
    mat[GENERATOR_KEY] = GENERATOR_VERSION


def _new_nodes(mat, model_id: str, p, form: str, fit=None):
    """The new layer node and, for a porous layer over a reference bulk that still feeds it, the new bulk node
    (a simple BSDF always as a node group, another model in ``form``), or None; nothing is left if either fails."""
    node = _new_node(mat, model_id, p, form, fit)
    layer = shader_node(mat)
    if not _has_reference_bulk(model_id, p) or (layer is not None and _user_bulk(layer)):
        return node, None
    bulk_id, params = MAPPINGS[model_id].bulk_shader(p)
    try:
        return node, _new_node(mat, bulk_id, params, "nodes" if bulk_id not in MODELS else form)
    except BaseException:
        mat.node_tree.nodes.remove(node)
        raise


def _new_node(mat, mapping_id: str, p, form: str, fit=None):
    """A new group or script node for ``p`` (with ``fit``: the fitted mapping) with its inputs set (removed again if
    anything fails)."""
    if form == "nodes":
        group = node_group(mapping_id, p, fit)
    else:
        text = osl_text(mapping_id, p, fit)
        oso = osl.compile_source(text.as_string())
    tree = mat.node_tree
    node = tree.nodes.new("ShaderNodeGroup" if form == "nodes" else "ShaderNodeScript")
    try:
        if form == "nodes":
            node.node_tree = group
        else:
            osl.load_into_script_node(node, oso)
            node.label = text.name
            node.inputs[TANGENT_INPUT].hide = True
        node.width = 240
        _write_values(node, input_values(mapping_id, p, form))
    except BaseException:
        tree.nodes.remove(node)
        raise
    return node


BULK_NODE = "Lamina Bulk"


def _has_reference_bulk(model_id: str, p) -> bool:
    """Whether ``p`` wraps a reference bulk that Lamina builds (the mapping's ``bulk_shader``)."""
    bulk_shader = getattr(MAPPINGS[model_id], "bulk_shader", None)
    return bulk_shader is not None and bulk_shader(p) is not None


def _user_bulk(layer) -> bool:
    """Whether a shader other than Lamina's bulk node feeds the layer's Bulk input (the user's: left alone)."""
    socket = layer.inputs[BULK_INPUT]
    return socket.is_linked and _bulk_node(layer) is None


def _place_bulk(mat, node) -> None:
    """Put the new bulk node (None: nothing to do) in place of ``Lamina Bulk``, feeding the layer's Bulk input."""
    if node is None:
        return
    tree = mat.node_tree
    layer = shader_node(mat)
    old = tree.nodes.get(BULK_NODE)
    if old is None:
        node.parent = layer.parent
        node.location = (layer.location.x - 300, layer.location.y)
    _replace(mat, old, node, BULK_NODE)
    socket = layer.inputs[BULK_INPUT]
    if not socket.is_linked:
        tree.links.new(node.outputs[0], socket)


HELPER_TAG = "lamina_helper"  # Lamina's helper nodes (the Geometry node feeding the OSL form's tangent)
BAKE_TAG = "lamina_bake"  # baked texture nodes (nodes.texture_wiring)


def _norm(name: str) -> str:
    """A socket name as both forms know it (OSL parameters are identifiers: "L1 Albedo" -> "L1_Albedo")."""
    return "".join(c if c.isalnum() else "_" for c in name)


def _helpers(tree, old) -> list:
    """Lamina's Geometry helper nodes: tagged ones, and (materials made before the tag) an untagged Geometry node
    whose only links go into the old Lamina node's tangent input."""
    found = []
    for n in tree.nodes:
        if n.get(HELPER_TAG):
            found.append(n)
        elif n.bl_idname == "ShaderNodeNewGeometry" and old is not None:
            links = [link for o in n.outputs for link in o.links]
            if links and all(link.to_node == old and link.to_socket.name == TANGENT_INPUT for link in links):
                found.append(n)
    return found


def _replace(mat, old, node, name: str = "Lamina") -> None:
    """Swap Lamina's node ``old`` (None: a new material, or one whose Lamina node was deleted) for ``node``; every
    other node stays. Links into ``old``'s inputs go to ``node``'s inputs of the same name (inputs that no longer
    exist lose theirs), its output links are re-created, its location, width and frame kept. The OSL form gets a
    Geometry helper (tagged) for its tangent; helpers and baked texture nodes (tagged) that end up feeding
    nothing are removed, untagged nodes never."""
    tree = mat.node_tree
    helpers = _helpers(tree, old)
    baked = []
    inputs, outputs = [], []
    if old is not None:
        node.parent = old.parent
        node.location = old.location
        node.width = old.width
        node.select = old.select
        for socket in old.inputs:
            for link in socket.links:
                if link.from_node not in helpers:
                    inputs.append((_norm(socket.name), link.from_socket, link.is_muted))
        for socket in old.outputs:
            for link in socket.links:
                outputs.append((_norm(socket.name), link.to_socket, link.is_muted))
        baked = [n for n in tree.nodes if n.get(BAKE_TAG) and any(o.is_linked for o in n.outputs)]
        active = tree.nodes.active == old
        _move_animation(tree, old, node)
        tree.nodes.remove(old)
        if active:
            tree.nodes.active = node
    node.name = name
    by_name = {_norm(s.name): s for s in node.inputs}
    for key, from_socket, muted in inputs:
        if key in by_name:
            tree.links.new(from_socket, by_name[key]).is_muted = muted
    by_name = {_norm(s.name): s for s in node.outputs}
    for key, to_socket, muted in outputs:
        if key in by_name:
            tree.links.new(by_name[key], to_socket).is_muted = muted
    if old is None and name == "Lamina":
        outs = [n for n in tree.nodes if n.bl_idname == "ShaderNodeOutputMaterial"]
        out = next((n for n in outs if n.is_active_output), outs[0] if outs else None)
        if out is None:
            out = tree.nodes.new("ShaderNodeOutputMaterial")
            out.location = (node.location.x + 300, node.location.y)
        if not out.inputs["Surface"].is_linked:
            tree.links.new(node.outputs["BSDF"], out.inputs["Surface"])
    if node.bl_idname == "ShaderNodeScript" and not node.inputs[TANGENT_INPUT].is_linked:
        if helpers:  # kept where the user moved it
            geometry = helpers.pop(0)
        else:
            geometry = tree.nodes.new("ShaderNodeNewGeometry")
            geometry.parent = node.parent
            geometry.location = (node.location.x - 300, node.location.y - 200)
        geometry[HELPER_TAG] = True
        tree.links.new(geometry.outputs["Tangent"], node.inputs[TANGENT_INPUT])
    for helper in helpers:
        if not any(o.is_linked for o in helper.outputs):
            tree.nodes.remove(helper)
    _prune(mat, baked)


def _prune(mat, candidates) -> None:
    """Remove the baked texture nodes among ``candidates`` that feed nothing any more (a Separate Color first,
    then the texture behind it), and their images when no one else uses them."""
    if not candidates:
        return
    names = {n.name for n in candidates}
    while True:
        unused = [n for n in mat.node_tree.nodes if n.name in names and not any(o.is_linked for o in n.outputs)]
        if not unused:
            return
        names -= {n.name for n in unused}
        remove_nodes(mat, unused)


def remove_nodes(mat, nodes, keep=()) -> None:
    """Remove ``nodes`` from ``mat`` and their images that nothing else uses (but those named in ``keep``)."""
    images = {n.image.name for n in nodes if getattr(n, "image", None) is not None} - set(keep)
    for n in nodes:
        mat.node_tree.nodes.remove(n)
    for name in images:
        image = bpy.data.images.get(name)
        if image is not None and image.users == 0:
            bpy.data.images.remove(image)


def socket_key(node, name: str) -> str:
    """The key of the input ``name`` of a Lamina node (a script node's sockets use identifier names)."""
    return name if node.bl_idname != "ShaderNodeScript" else _norm(name)


def _write_values(node, values: dict) -> bool:
    """Set the node's unlinked inputs (a linked one is driven by its link; one fed by Lamina's view lookup keeps the
    value it falls back to without it); True if any value changed. Equal values are not rewritten, so a repeated
    bake triggers no depsgraph update."""
    changed = False
    for name, value in values.items():
        socket = node.inputs[socket_key(node, name)]
        new = _socket_value(value, socket.default_value)
        if (socket.is_linked and not view_wiring.fed(socket)) or _same(socket.default_value, new):
            continue
        socket.default_value = new
        changed = True
    return changed


def _same(current, new) -> bool:
    pairs = zip(current, new) if hasattr(current, "__len__") else [(current, new)]
    return all(math.isclose(a, b, rel_tol=1e-6, abs_tol=1e-9) for a, b in pairs)


def _read_socket(node, s):
    v = node.inputs[socket_key(node, s.name)].default_value
    return float(v) if s.kind == "float" else tuple(float(x) for x in v[:3])

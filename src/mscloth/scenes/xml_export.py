"""Writing mscloth's scene dictionaries as Mitsuba 3 XML, so users can start from a
built-in scene in their own files."""
from __future__ import annotations

from xml.sax.saxutils import quoteattr

import mitsuba as mi

from ..errors import ClothError

#: Plugin type -> XML tag.
CATEGORY = {
    "clothpath": "integrator", "path": "integrator",
    "perspective": "sensor", "hdrfilm": "film", "independent": "sampler", "multijitter": "sampler", "stratified": "sampler",
    "ldsampler": "sampler", "orthogonal": "sampler", "box": "rfilter",
    "constant": "emitter", "directional": "emitter", "area": "emitter", "sunsky": "emitter",
    "rectangle": "shape", "sphere": "shape", "ply": "shape", "obj": "shape", "cylinder": "shape",
    "cloth": "bsdf", "diffuse": "bsdf", "principled": "bsdf", "roughconductor": "bsdf",
}
#: Property names written as <point> rather than <vector>.
POINTS = {"center", "origin", "target"}


def _number(x) -> str:
    return repr(float(x))


def _property(name: str, value, indent: str) -> str:
    attr = quoteattr(name)
    if isinstance(value, bool):
        return f'{indent}<boolean name={attr} value="{str(value).lower()}"/>'
    if isinstance(value, int):
        return f"{indent}<integer name={attr} value=\"{value}\"/>"
    if isinstance(value, float):
        return f"{indent}<float name={attr} value=\"{_number(value)}\"/>"
    if isinstance(value, str):
        return f"{indent}<string name={attr} value={quoteattr(value)}/>"
    if isinstance(value, mi.ScalarTransform4f):
        matrix = " ".join(_number(v) for row in value.matrix.numpy().tolist() for v in row)
        return f'{indent}<transform name={attr}>\n{indent}    <matrix value="{matrix}"/>\n{indent}</transform>'
    if isinstance(value, (list, tuple)) and len(value) == 3:
        tag = "point" if name in POINTS else "vector"
        x, y, z = (_number(v) for v in value)
        return f'{indent}<{tag} name={attr} x="{x}" y="{y}" z="{z}"/>'
    if isinstance(value, dict):
        return _object(name, value, indent)
    raise ClothError(f"cannot write scene property {name!r} of type {type(value).__name__} as XML")


def _object(name: str, node: dict, indent: str, top: bool = False) -> str:
    kind = node.get("type")
    if kind == "rgb":
        value = node["value"]
        rgb = ", ".join(_number(v) for v in (value if isinstance(value, (list, tuple)) else [value] * 3))
        return f"{indent}<rgb name={quoteattr(name)} value=\"{rgb}\"/>"
    if kind not in CATEGORY:
        raise ClothError(f"cannot write plugin type {kind!r} (at {name!r}) as XML")
    tag = CATEGORY[kind]
    head = f"{indent}<{tag} type={quoteattr(kind)}"
    # Ids for the scene's own shapes and emitters (a light's nested emitter needs none).
    head += f" id={quoteattr(name)}>" if top and tag in ("shape", "emitter") else ">"
    body = [_property(key, value, indent + "    ") for key, value in node.items() if key != "type"]
    return "\n".join([head, *body, f"{indent}</{tag}>"])


def scene_to_xml(scene: dict) -> str:
    """The XML text of a scene dictionary made of the plugin types in :data:`CATEGORY`."""
    if scene.get("type") != "scene":
        raise ClothError("scene_to_xml: expected a dictionary with type 'scene'")
    body = [_object(key, value, "    ", top=True) for key, value in scene.items() if key != "type"]
    return "\n".join(['<scene version="3.0.0">', *body, "</scene>", ""])

"""Pixel footprints for shading points: ray differentials at the first hit, ray cones after.

Pure functions on Dr.Jit arrays of the active Mitsuba variant (no scene, no state), used by
the ``clothpath`` integrator and testable on their own.

Convention (shared with the ``cloth`` BSDF)
-------------------------------------------
A shading point receives its footprint in ``si.duv_dx`` / ``si.duv_dy``: the UV change for
one pixel step along the two image axes. The footprint of the point is the axis-aligned UV
rectangle centred on ``si.uv`` with half-widths

    h_u = 1/2 (|du/dx| + |du/dy|),    h_v = 1/2 (|dv/dx| + |dv/dy|)

(:func:`half_widths`). The ``cloth`` BSDF multiplies these by its ``uv_scale`` and the tile
resolution to get texels.

First hit: ray differentials
----------------------------
Camera rays carry differentials (the rays through the neighbouring pixel centres). Mitsuba's
render loop scales them by 1/sqrt(spp) before calling ``SamplingIntegrator.sample`` (in 3.9.1:
``ray.scale_differential(rsqrt(spp))`` in ``render_sample``, spp = ``sampler.sample_count()``),
which :func:`undo_differential_scaling` reverts, so the footprint is the whole pixel whatever
the sample count. :func:`differential_footprint` intersects the offset rays with the tangent
plane and solves for the UV partials like ``SurfaceInteraction3f.compute_uv_partials``, but
robustly (:func:`world_to_uv`).

Centring on the pixel (first hit)
---------------------------------
A camera sample lies somewhere inside its pixel. A footprint centred on the sample's own uv
would make the image the pixel box filtered twice (a tent two pixels wide), blurrier than
brute-force supersampling, and would keep the texture noise of where the sample fell. At
the first hit ``clothpath`` therefore hands footprint-aware BSDFs (those with
``eval_pdf_sample_n``, i.e. ``cloth``) the uv of the pixel centre: the sample's uv moved by
``-(duv_dx * ox + duv_dy * oy)`` with ``(ox, oy)`` its offset from the pixel centre in pixels
(:func:`pixel_centring`: perspective and orthographic cameras; other sensors keep the
sample's uv).

Later hits: ray cones
---------------------
After the first hit the path carries a cone (Akenine-Moller et al. 2019, "Texture level of
detail strategies for real-time ray tracing"; 2021, "Improved shader and texture level of
detail using ray cones"): a width ``W`` (diameter perpendicular to the ray) and a spread
angle ``gamma`` (full apex angle, radians). The camera gives ``W0`` (width at the ray origin:
0 for a pinhole) and ``gamma0`` (the angle between neighbouring pixels' rays),
:func:`camera_cone`. Along a segment of length ``t`` the width grows linearly,
``W <- W + gamma * t`` (:func:`cone_width`, the small-angle ray-cone rule).

Spread rule at a bounce (:func:`bounce_spread`). The cone must widen with the roughness of the
BSDF lobe, but Mitsuba's BSDF interface exposes no roughness; what every BSDF does expose is
the density ``pdf`` (per steradian) of the direction it sampled. A lobe of density ``p`` covers
an effective solid angle ``1/p``; a cone of that solid angle has apex angle ``2/sqrt(pi p)``
(small-angle), so

    gamma <- min(gamma + beta, MAX_SPREAD),   beta = 0 for delta samples,
                                              beta = 2 / sqrt(pi * pdf) otherwise.

This is the path-differential rule of Suykens & Willems 2001 (a sampled direction's angular
footprint ~ 1/sqrt(pdf)) in ray-cone form. It needs no knowledge of the BSDF: a mirror
(delta) keeps the camera spread, so a flat mirror shows the footprint of the total distance;
a GGX lobe of roughness 0.1 at normal incidence (pdf ~ 8) adds about 0.4 rad; a diffuse
bounce (pdf <= 1/pi) adds about 2 rad, capped at ``MAX_SPREAD`` = pi/2 (beyond that the
linear cone is meaningless). The sampled pdf is random, so the footprint after a rough
bounce is too: it is a filtering width, not an estimator weight, so no bias is introduced
in the light transport, only in the filtered BSDF's choice of scale. Not modelled: surface
curvature (the ``beta`` of Akenine-Moller et al. for curved mirrors) and refraction's angular
compression.

Cone to UV (:func:`cone_footprint`): the cone's disk of diameter ``W`` projects along the ray
onto the tangent plane as an ellipse with semi-axes ``W/2`` (across the plane of incidence)
and ``W/(2|cos theta|)`` (in it). Mapped to UV through ``dp_du``, ``dp_dv`` it stays an ellipse;
its axis-aligned bounding box has half-widths (h_u, h_v), returned as the two orthogonal UV
vectors ``duv_dx = (2 h_u, 0)``, ``duv_dy = (0, 2 h_v)``, so the convention above gives back
exactly that box.

Degenerate cases: where ``dp_du`` (or ``dp_dv``) vanishes, e.g. at a sphere's pole, all values
of u meet at one point, so a footprint of positive size covers the whole u range: the UV
offset along that axis is set to one UV unit. Every footprint is then capped
(:func:`cap_footprint`) so that its half-widths do not exceed ``MAX_HALF_WIDTH`` = 1/2, i.e.
the rectangle is at most the unit UV square (also at grazing angles, where the footprint
diverges). Nothing returns NaN or infinity.
"""
from __future__ import annotations

import math

import drjit as dr
import mitsuba as mi

#: Largest footprint half-width in UV: the rectangle is at most the unit UV square.
MAX_HALF_WIDTH = 0.5
#: UV offset given to a world displacement along a degenerate axis (dp_dk = 0): one UV unit.
DEGENERATE_UV = 1.0
#: Cap on a cone's spread angle (full apex angle, radians).
MAX_SPREAD = 0.5 * math.pi
#: Smallest |cos theta| used when projecting a cone onto a surface (grazing cap, 1000x).
MIN_COS = 1e-3
#: dp_du, dp_dv count as parallel below this sin^2 of the angle between them.
_PARALLEL_SIN2 = 1e-6
#: An axis is degenerate when |dp_dk|^2 is below this fraction of |dp_du|^2 + |dp_dv|^2.
_DEGENERATE_REL = 1e-12


def undo_differential_scaling(ray, spp):
    """A copy of ``ray`` whose differentials span a whole pixel again.

    Mitsuba's render loop calls ``ray.scale_differential(1/sqrt(spp))`` before
    ``sample()``; this applies the inverse factor ``sqrt(spp)`` (``spp`` >= 1).
    """
    # Field by field: RayDifferential3f(ray) does not copy the differentials.
    out = mi.RayDifferential3f(ray.o, ray.d, ray.time, ray.wavelengths)
    out.maxt = ray.maxt
    if not ray.has_differentials:
        return out
    k = math.sqrt(float(max(spp, 1)))
    out.o_x = dr.fma(ray.o_x - ray.o, k, ray.o)
    out.o_y = dr.fma(ray.o_y - ray.o, k, ray.o)
    out.d_x = dr.fma(ray.d_x - ray.d, k, ray.d)
    out.d_y = dr.fma(ray.d_y - ray.d, k, ray.d)
    out.has_differentials = True
    return out


def camera_cone(o, d, o_x, d_x, o_y, d_y):
    """(width at the ray origin, spread angle) of the cone of a camera ray with differentials.

    Width: mean distance of the offset rays' origins (0 for a pinhole, the pixel size for an
    orthographic camera); spread: mean angle between ``d`` and the offset directions.
    """
    width = 0.5 * (dr.norm(o_x - o) + dr.norm(o_y - o))
    dn = dr.normalize(d)
    spread = 0.5 * (_angle_between(dn, dr.normalize(d_x)) + _angle_between(dn, dr.normalize(d_y)))
    return width, spread


def _angle_between(a, b):
    """Angle between unit vectors, accurate for small angles (2 asin(|a - b| / 2))."""
    return 2.0 * dr.safe_asin(0.5 * dr.norm(a - b))


def cone_width(width, spread, distance):
    """Width of a cone after travelling ``distance``: ``width + spread * distance``."""
    return dr.fma(spread, distance, width)


def bounce_spread(spread, pdf, delta, max_spread=MAX_SPREAD):
    """Spread angle after a BSDF sample (see the module docstring for the rule).

    ``pdf``: solid-angle density of the sampled direction; ``delta``: whether the sampled
    component is a delta lobe (then the spread is unchanged).
    """
    lobe = 2.0 * dr.rsqrt(math.pi * dr.maximum(pdf, 1e-20))
    lobe = dr.select(delta | (pdf <= 0) | dr.isnan(pdf), 0.0, lobe)
    lobe = dr.select(dr.isfinite(lobe), lobe, max_spread)
    return dr.minimum(spread + lobe, max_spread)


def world_to_uv(q, dp_du, dp_dv):
    """UV offset whose surface displacement best matches the world vector ``q``.

    Least squares in the tangent plane, as in ``compute_uv_partials``; a degenerate axis
    (``|dp_dk|`` ~ 0) gets ``DEGENERATE_UV`` when ``q`` is nonzero, parallel ``dp_du``, ``dp_dv``
    are solved per axis, and non-finite results become ``DEGENERATE_UV``. Not capped.
    """
    a00 = dr.dot(dp_du, dp_du)
    a01 = dr.dot(dp_du, dp_dv)
    a11 = dr.dot(dp_dv, dp_dv)
    b0 = dr.dot(dp_du, q)
    b1 = dr.dot(dp_dv, q)
    total = a00 + a11
    ok_u = (a00 > _DEGENERATE_REL * total) & (a00 > 0)
    ok_v = (a11 > _DEGENERATE_REL * total) & (a11 > 0)
    det = dr.fma(a00, a11, -a01 * a01)
    well = ok_u & ok_v & (det > _PARALLEL_SIN2 * a00 * a11)

    inv_det = dr.select(well, dr.rcp(dr.select(well, det, 1.0)), 0.0)
    u_full = dr.fma(a11, b0, -a01 * b1) * inv_det
    v_full = dr.fma(a00, b1, -a01 * b0) * inv_det
    u_axis = b0 / dr.select(ok_u, a00, 1.0)
    v_axis = b1 / dr.select(ok_v, a11, 1.0)
    nonzero = dr.squared_norm(q) > 0
    fill = dr.select(nonzero, DEGENERATE_UV, 0.0)
    u = dr.select(well, u_full, dr.select(ok_u, u_axis, fill))
    v = dr.select(well, v_full, dr.select(ok_v, v_axis, fill))
    return mi.Vector2f(_finite_or(u, DEGENERATE_UV), _finite_or(v, DEGENERATE_UV))


#: Shapes whose si.dn_du, si.dn_dv Mitsuba gives per UV, or zero (``mi.ShapeType``: the
#: rectangle and the disk are flat meshes; instances and anything else may hold meshes).
_UV_DERIVATIVE_SHAPES = ("Sphere", "Cylinder", "Disk", "Rectangle", "BSplineCurve", "LinearCurve", "SDFGrid",
                         "Ellipsoids", "EllipsoidsMesh")


def needs_uv_normal_derivatives(scene) -> bool:
    """Whether a shape of ``scene`` may give si.dn_du, si.dn_dv per barycentric unit with
    UVs of its own: a triangle mesh with vertex normals and texcoords (one without normals
    has none; one without texcoords, barycentric UVs), or a shape that may hold one. Where
    none can, :func:`uv_normal_derivatives` is not traced (its calls cost a frame ~5%)."""
    known = {int(getattr(mi.ShapeType, name)) for name in _UV_DERIVATIVE_SHAPES if hasattr(mi.ShapeType, name)}
    for shape in scene.shapes():
        if int(shape.shape_type()) in known:
            continue
        if isinstance(shape, mi.Mesh) and not (shape.has_vertex_normals() and shape.has_vertex_texcoords()):
            continue
        return True
    return False


def uv_normal_derivatives(si, active=True):
    """(dn/du, dn/dv) of the shading normal per unit of texture UV, as Mitsuba's analytic
    shapes give si.dn_du, si.dn_dv (RayFlags.dNSdUV). Mitsuba 3's triangle meshes give them
    per unit of the triangle's barycentric coordinates (mesh.cpp) while their si.dp_du,
    si.dp_dv are per UV: on a mesh with texture coordinates they are taken through the
    inverse of the texcoords' Jacobian (the solve Mitsuba does for dp_du, dp_dv). A mesh
    without texcoords has barycentric UVs, which already agree. Scalar variants keep
    Mitsuba's (their hit's shape comes to Python as a Shape, without the mesh's methods):
    fewer cells on curved meshes there."""
    shape = si.shape
    if not dr.is_jit_v(mi.Float):  # scalar: one shading point
        if not (active and si.is_valid() and isinstance(shape, mi.Mesh) and shape.has_vertex_texcoords()):
            return si.dn_du, si.dn_dv
        fi = shape.face_indices(si.prim_index)
        uv0, uv1, uv2 = (shape.vertex_texcoord(fi[k]) for k in range(3))
        return _barycentric_to_uv(si.dn_du, si.dn_dv, uv1 - uv0, uv2 - uv0, True)
    on = active & si.is_valid() & si.shape.is_mesh()
    # Null pointers where not a mesh: calls there return zeros.
    mesh = mi.MeshPtr(dr.select(on, si.shape, dr.zeros(mi.ShapePtr, dr.width(on))))
    on &= mesh.has_vertex_texcoords()
    fi = mesh.face_indices(si.prim_index, on)
    uv0, uv1, uv2 = (mesh.vertex_texcoord(fi[k], on) for k in range(3))
    return _barycentric_to_uv(si.dn_du, si.dn_dv, uv1 - uv0, uv2 - uv0, on)


def _barycentric_to_uv(n1, n2, d1, d2, on):
    """dn/duv from dn/db1 = ``n1``, dn/db2 = ``n2`` where UV = uv0 + b1 ``d1`` + b2 ``d2``
    (unchanged where not ``on`` or the texcoords are degenerate)."""
    det = d1.x * d2.y - d1.y * d2.x
    ok = on & (det != 0.0)
    inv = dr.select(ok, dr.rcp(dr.select(ok, det, 1.0)), 0.0)
    dn_du = (n1 * d2.y - n2 * d1.y) * inv
    dn_dv = (n2 * d1.x - n1 * d2.x) * inv
    return dr.select(ok, dn_du, n1), dr.select(ok, dn_dv, n2)


def _finite_or(x, value):
    return dr.select(dr.isfinite(x), x, value)


def cap_footprint(duv_dx, duv_dy, max_half_width=MAX_HALF_WIDTH):
    """(duv_dx, duv_dy) with non-finite components replaced and the u (v) components of both
    scaled down so that the half-width along u (v), see :func:`half_widths`, is at most
    ``max_half_width``."""
    dx = mi.Vector2f(_finite_or(duv_dx.x, DEGENERATE_UV), _finite_or(duv_dx.y, DEGENERATE_UV))
    dy = mi.Vector2f(_finite_or(duv_dy.x, DEGENERATE_UV), _finite_or(duv_dy.y, DEGENERATE_UV))
    h_u, h_v = half_widths(dx, dy)
    s_u = dr.select(h_u > max_half_width, max_half_width / dr.select(h_u > 0, h_u, 1.0), 1.0)
    s_v = dr.select(h_v > max_half_width, max_half_width / dr.select(h_v > 0, h_v, 1.0), 1.0)
    return mi.Vector2f(dx.x * s_u, dx.y * s_v), mi.Vector2f(dy.x * s_u, dy.y * s_v)


def differential_footprint(p, n, dp_du, dp_dv, o_x, d_x, o_y, d_y):
    """(duv_dx, duv_dy) at a hit point from the (whole-pixel) offset rays of a ray differential.

    The offset rays are intersected with the tangent plane at ``p`` (normal ``n``); their
    displacements from ``p`` are mapped to UV by :func:`world_to_uv`. An offset ray parallel to
    the plane (grazing) gives the capped footprint (:func:`cap_footprint`).
    """
    def offset(o_k, d_k):
        denom = dr.dot(n, d_k)
        t = dr.dot(n, p - o_k) / dr.select(denom != 0, denom, 1.0)  # no raise in scalar mode
        q = dr.fma(d_k, t, o_k) - p
        finite = dr.isfinite(t) & (denom != 0) & dr.all(dr.isfinite(q))
        big = mi.Vector2f(DEGENERATE_UV, DEGENERATE_UV)
        return dr.select(finite, world_to_uv(dr.select(finite, q, 0.0), dp_du, dp_dv), big)

    return cap_footprint(offset(o_x, d_x), offset(o_y, d_y))


def cone_footprint(width, d, n, dp_du, dp_dv):
    """(duv_dx, duv_dy) for a ray cone of ``width`` hitting a surface along unit ``d``.

    The cone's disk projects to an ellipse on the tangent plane (normal ``n``); the result is
    the two orthogonal UV vectors ``(2 h_u, 0)`` and ``(0, 2 h_v)`` of the ellipse's axis-aligned
    UV bounding box (half-widths h_u, h_v), capped by :func:`cap_footprint`.
    """
    cos_t = dr.maximum(dr.abs(dr.dot(d, n)), MIN_COS)
    across = dr.cross(d, n)
    length = dr.norm(across)
    fallback = mi.Frame3f(n).s  # near normal incidence the ellipse is a circle: any axis
    a1 = dr.select(length > 1e-6, across / dr.select(length > 0, length, 1.0), fallback)
    a2 = dr.cross(n, a1)
    r = 0.5 * width
    e1 = world_to_uv(r * a1, dp_du, dp_dv)
    e2 = world_to_uv((r / cos_t) * a2, dp_du, dp_dv)
    h_u = dr.sqrt(dr.fma(e1.x, e1.x, e2.x * e2.x))
    h_v = dr.sqrt(dr.fma(e1.y, e1.y, e2.y * e2.y))
    return cap_footprint(mi.Vector2f(2.0 * h_u, 0.0), mi.Vector2f(0.0, 2.0 * h_v))


def half_widths(duv_dx, duv_dy):
    """Footprint half-widths (h_u, h_v) = 1/2 (|du/dx| + |du/dy|), 1/2 (|dv/dx| + |dv/dy|)."""
    return (0.5 * (dr.abs(duv_dx.x) + dr.abs(duv_dy.x)),
            0.5 * (dr.abs(duv_dx.y) + dr.abs(duv_dy.y)))


def pixel_centre_offset(sensor, p, active=True):
    """(ox, oy, valid): the offset in pixels, each in [-1/2, 1/2), of the film position at
    which ``sensor`` (a perspective camera) sees the point ``p`` from its pixel's centre.

    Uses the camera's own projection (``Sensor.sample_direction`` returns raster
    coordinates of its crop window in ``uv``, also beyond the window, where its pdf is 0: a
    point of the frame outside a crop, as the sky-share pilot renders, is centred as in the
    whole frame); ``valid`` is false behind the camera."""
    it = dr.zeros(mi.Interaction3f, dr.width(p))
    it.p = p
    ds, _ = sensor.sample_direction(it, mi.Point2f(0.5, 0.5), active)
    fx = ds.uv.x - dr.floor(ds.uv.x)
    fy = ds.uv.y - dr.floor(ds.uv.y)
    to_world = sensor.world_transform()
    forward = to_world @ mi.Vector3f(0.0, 0.0, 1.0)
    in_front = dr.dot(p - mi.Point3f(to_world.translation()), forward) > 0.0
    valid = active & in_front & dr.isfinite(ds.uv.x) & dr.isfinite(ds.uv.y)
    return fx - 0.5, fy - 0.5, valid


def orthographic_centre_offset(o, corner, step_x, step_y, active=True):
    """(ox, oy, valid): the offset in pixels, each in [-1/2, 1/2), of an orthographic
    camera ray with origin ``o`` from its pixel's centre. The origins are affine in the film
    position, o = corner + px step_x + py step_y, with (px, py) in pixels from the crop
    window's corner, ``corner`` the origin there and ``step_x``, ``step_y`` (orthogonal) the
    origins' offsets per pixel: the whole-pixel ray differentials o_x - o, o_y - o."""
    rel = o - corner
    nx = dr.squared_norm(step_x)
    ny = dr.squared_norm(step_y)
    valid = active & (nx > 0.0) & (ny > 0.0)
    px = dr.dot(rel, step_x) / dr.select(valid, nx, 1.0)
    py = dr.dot(rel, step_y) / dr.select(valid, ny, 1.0)
    valid &= dr.isfinite(px) & dr.isfinite(py)
    return px - dr.floor(px) - 0.5, py - dr.floor(py) - 0.5, valid


def pixel_centring(scene, ray):
    """For camera rays ``ray`` (whole-pixel differentials): a function (p, active) ->
    (ox, oy, valid) giving each lane's offset from its pixel centre (``p``: the point the ray
    hits), for the scene's perspective or orthographic camera; lanes whose ray does not come
    from that camera are not valid. None when the scene has neither."""
    d = dr.normalize(ray.d)
    for sensor in scene.sensors():
        name = sensor.class_name()
        if name == "PerspectiveCamera":
            # Camera rays' lines pass through the centre of projection.
            origin = mi.Point3f(sensor.world_transform().translation())
            from_camera = dr.norm(dr.cross(origin - ray.o, d)) <= 1e-5 * (1.0 + dr.norm(origin))
            return lambda p, active: pixel_centre_offset(sensor, p, active & from_camera)
        if name == "OrthographicCamera":
            # Camera rays run along the view axis; Mitsuba 3.9.1's orthographic camera has
            # no sample_direction, so invert its (affine) film-to-origin map instead.
            forward = dr.normalize(sensor.world_transform() @ mi.Vector3f(0.0, 0.0, 1.0))
            from_camera = dr.norm(dr.cross(mi.Vector3f(forward), d)) <= 1e-5
            corner_ray, _ = sensor.sample_ray(0.0, 0.5, mi.Point2f(0.0, 0.0), mi.Point2f(0.5, 0.5))
            o, step_x, step_y = ray.o, ray.o_x - ray.o, ray.o_y - ray.o
            return lambda p, active: orthographic_centre_offset(o, corner_ray.o, step_x, step_y,
                                                                active & from_camera)
    return None


def centred_uv(uv, duv_dx, duv_dy, ox, oy):
    """uv of the pixel centre from a sample's uv and its offset (ox, oy) in pixels."""
    return uv - duv_dx * ox - duv_dy * oy

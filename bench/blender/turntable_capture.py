# Synthetic turntable reflectance capture with Blender Cycles, in capture/1 format.
#
#   blender -b -noaudio -P bench/blender/turntable_capture.py -- \
#       --object knot --seed 2 --res 320 --spp 32 --out /tmp/blender_caps/knot
#   blender -b -noaudio -P bench/blender/turntable_capture.py -- --check /tmp/blender_caps/knot
#   blender -b -noaudio -P bench/blender/turntable_capture.py -- \
#       --object teapot --rig suzanne --seed 3 --res 320 --spp 32 --out /tmp/blender_caps/teapot
#
# Objects: knot (torus-knot tube, own rig) and teapot (body of revolution with lid and knob,
# handle, spout; suzanne's rig by default). --rig knot|suzanne picks the cameras, lights and
# holdout split; "suzanne" is exactly the rig of shared/data/turntable/suzanne.
#
# The first command builds the object, bakes its ground-truth textures, writes mesh.obj,
# renders every (turntable angle, camera, light) photograph, renders the silhouette masks and
# writes capture.json. The second reads only the files (capture.json, mesh.obj, PNGs, EXRs) and
# checks them: image sanity, masks against an independent rasterisation of mesh.obj with the
# file's K / cam_from_world / turntable, photographs against masks, UV overlaps, and radiometry
# (observed radiance against Lambert and an approximate Principled direct-light model).
# Conventions follow shared/data/CAPTURE_FORMAT.md and the suzanne capture's README.

import argparse
import json
import math
import os
import struct
import sys
import time
import zlib

import bpy
import bmesh
import numpy as np
from mathutils import Matrix, Vector
from mathutils.bvhtree import BVHTree

# ----------------------------------------------------------------------------------------------
# Rigs (world frame: z up; azimuth from +x towards +y; elevation above the target's z plane).
# The cameras look at the object's bounding-box centre (the "target"); the lights are placed
# around the same point. "knot" is the knot capture's own rig; "suzanne" is the rig of
# shared/data/turntable/suzanne (its README and capture.json), with its fx = fy = 768 px kept.
RIGS = {
    "knot": {
        "cam_el": [15.0, 40.0, 65.0], "cam_az": 0.0, "cam_dist": 0.75,
        "fx": None,                  # None: fx so that the bounding box spans target_span
        "target_span": 0.5,          # object bounding box / frame width, averaged over the views
        "light_el": [25.0, 55.0], "light_az": [-150.0, -90.0, -30.0, 30.0, 90.0, 150.0],
        "holdout_angles": [120.0, 240.0], "holdout_lights": ["L7"]},
    "suzanne": {
        "cam_el": [10.0, 30.0, 50.0, 70.0], "cam_az": 0.0, "cam_dist": 0.80,
        "fx": 768.0, "target_span": None,
        "light_el": [20.0, 45.0, 70.0], "light_az": [-90.0, -30.0, 30.0, 90.0, 150.0],
        "holdout_angles": [90.0, 270.0], "holdout_lights": ["L9"]},
}
LIGHT_DIST = 1.0
LIGHT_RADIUS = 0.002
LIGHT_POWER = 30.0
ANGLES = [30.0 * i for i in range(12)]
# Holdout angles are those angles (as suzanne's [90, 270]), not the interval between them.
OBJECT_SIZE = 0.2            # metres, largest bounding-box side
TEX_RES = 1024
BAKE_MARGIN = 12

# Base-colour palette (sRGB-encoded, 0..255): saturated and pastel.
PALETTE_SRGB = [
    (0, 150, 136),    # teal
    (245, 124, 0),    # orange
    (194, 24, 91),    # magenta-pink
    (124, 179, 66),   # leaf green
    (30, 80, 200),    # cobalt
    (200, 40, 40),    # crimson
    (240, 190, 30),   # saffron
    (110, 60, 170),   # violet
    (200, 180, 235),  # lavender
    (170, 230, 200),  # mint
    (250, 200, 170),  # peach
    (165, 205, 240),  # baby blue
    (245, 235, 160),  # pale yellow
    (240, 175, 200),  # rose
]


# ----------------------------------------------------------------------------------------------
# Small helpers: colour, PNG i/o, EXR reading through Blender, vectorised rasteriser.

def srgb_to_linear(c):
    c = np.asarray(c, dtype=np.float64)
    return np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)


def linear_to_srgb(c):
    c = np.clip(np.asarray(c, dtype=np.float64), 0.0, 1.0)
    return np.where(c <= 0.0031308, c * 12.92, 1.055 * c ** (1.0 / 2.4) - 0.055)


def write_png(path, arr):
    """8-bit grey (H,W) or RGB (H,W,3) array, row 0 = top row of the picture."""
    arr = np.ascontiguousarray(arr, dtype=np.uint8)
    h, w = arr.shape[:2]
    ch = 1 if arr.ndim == 2 else arr.shape[2]
    colour_type = {1: 0, 3: 2}[ch]
    raw = np.zeros((h, 1 + w * ch), dtype=np.uint8)   # filter byte 0 per row
    raw[:, 1:] = arr.reshape(h, w * ch)

    def chunk(tag, data):
        return (struct.pack(">I", len(data)) + tag + data
                + struct.pack(">I", zlib.crc32(tag + data) & 0xFFFFFFFF))

    png = b"\x89PNG\r\n\x1a\n"
    png += chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, 8, colour_type, 0, 0, 0))
    png += chunk(b"IDAT", zlib.compress(raw.tobytes(), 9))
    png += chunk(b"IEND", b"")
    with open(path, "wb") as f:
        f.write(png)


def read_png(path):
    """Reads 8-bit grey/RGB/RGBA non-interlaced PNGs (all five row filters)."""
    with open(path, "rb") as f:
        data = f.read()
    assert data[:8] == b"\x89PNG\r\n\x1a\n", path
    pos, idat, hdr = 8, b"", None
    while pos < len(data):
        n = struct.unpack(">I", data[pos:pos + 4])[0]
        tag = data[pos + 4:pos + 8]
        body = data[pos + 8:pos + 8 + n]
        if tag == b"IHDR":
            hdr = struct.unpack(">IIBBBBB", body)
        elif tag == b"IDAT":
            idat += body
        pos += 12 + n
    w, h, depth, ctype, _, _, interlace = hdr
    assert depth == 8 and interlace == 0, path
    ch = {0: 1, 2: 3, 4: 2, 6: 4}[ctype]
    raw = np.frombuffer(zlib.decompress(idat), dtype=np.uint8).reshape(h, 1 + w * ch)
    out = np.zeros((h, w * ch), dtype=np.int32)
    for y in range(h):
        ft, line = raw[y, 0], raw[y, 1:].astype(np.int32)
        prev = out[y - 1] if y > 0 else np.zeros(w * ch, dtype=np.int32)
        if ft == 0:
            cur = line
        elif ft == 2:
            cur = (line + prev) & 255
        else:
            cur = np.zeros(w * ch, dtype=np.int32)
            for x in range(w * ch):
                a = cur[x - ch] if x >= ch else 0
                b = prev[x]
                c = prev[x - ch] if x >= ch else 0
                if ft == 1:
                    p = a
                elif ft == 3:
                    p = (a + b) // 2
                else:
                    pa, pb, pc = abs(b - c), abs(a - c), abs(a + b - 2 * c)
                    p = a if (pa <= pb and pa <= pc) else (b if pb <= pc else c)
                cur[x] = (line[x] + p) & 255
        out[y] = cur
    out = out.astype(np.uint8)
    return out.reshape(h, w) if ch == 1 else out.reshape(h, w, ch)


def read_exr(path):
    """Float RGB (H,W,3), row 0 = top, through Blender's image loader (no colour transform)."""
    img = bpy.data.images.load(path, check_existing=False)
    img.colorspace_settings.name = "Non-Color"
    w, h = img.size
    px = np.empty(w * h * 4, dtype=np.float32)
    img.pixels.foreach_get(px)
    bpy.data.images.remove(img)
    return px.reshape(h, w, 4)[::-1, :, :3].copy()


def rasterize(p2, tris, width, height, depth=None, budget=4_000_000):
    """Pixel-centre rasterisation. p2: (V,2) positions in pixel units, pixel (i, j) centred at
    integer (i, j). Returns (pix_index, tri_index, barycentrics). With depth (V,), keeps the
    nearest triangle per pixel (screen-space barycentrics; the caller corrects perspective)."""
    a, b, c = p2[tris[:, 0]], p2[tris[:, 1]], p2[tris[:, 2]]
    lo = np.floor(np.minimum(np.minimum(a, b), c)).astype(np.int64)
    hi = np.ceil(np.maximum(np.maximum(a, b), c)).astype(np.int64)
    size = np.maximum(hi[:, 0] - lo[:, 0], hi[:, 1] - lo[:, 1]) + 1
    area = (b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (b[:, 1] - a[:, 1]) * (c[:, 0] - a[:, 0])
    ok = (np.abs(area) > 1e-12) & (hi[:, 0] >= 0) & (hi[:, 1] >= 0) & \
         (lo[:, 0] < width) & (lo[:, 1] < height)
    out_pix, out_tri, out_bary = [], [], []
    k_prev = 0
    k = 1
    while k_prev < (size[ok].max() if ok.any() else 0):
        sel = np.nonzero(ok & (size > k_prev) & (size <= k))[0]
        oy, ox = np.mgrid[0:k, 0:k]
        ox, oy = ox.ravel(), oy.ravel()
        step = max(1, budget // (k * k))
        for s0 in range(0, len(sel), step):
            t = sel[s0:s0 + step]
            px = lo[t, 0:1] + ox[None, :]
            py = lo[t, 1:2] + oy[None, :]
            ax, ay = a[t, 0:1], a[t, 1:2]
            bx, by = b[t, 0:1], b[t, 1:2]
            cx, cy = c[t, 0:1], c[t, 1:2]
            w0 = (bx - px) * (cy - py) - (by - py) * (cx - px)
            w1 = (cx - px) * (ay - py) - (cy - py) * (ax - px)
            w2 = (ax - px) * (by - py) - (ay - py) * (bx - px)
            ar = area[t][:, None]
            w0, w1, w2 = w0 / ar, w1 / ar, w2 / ar
            inside = (w0 >= 0) & (w1 >= 0) & (w2 >= 0) & (px >= 0) & (py >= 0) & \
                     (px < width) & (py < height)
            ti, ci = np.nonzero(inside)
            out_pix.append(py[ti, ci] * width + px[ti, ci])
            out_tri.append(t[ti])
            out_bary.append(np.stack([w0[ti, ci], w1[ti, ci], w2[ti, ci]], 1))
        k_prev = k
        k *= 2
    if not out_pix:
        return np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros((0, 3))
    pix = np.concatenate(out_pix)
    tri = np.concatenate(out_tri)
    bary = np.concatenate(out_bary)
    if depth is not None:
        z = (bary * depth[tris[tri]]).sum(1)
        order = np.lexsort((z, pix))
        pix, tri, bary = pix[order], tri[order], bary[order]
        first = np.ones(len(pix), bool)
        first[1:] = pix[1:] != pix[:-1]
        pix, tri, bary = pix[first], tri[first], bary[first]
    return pix, tri, bary


def rot_z(deg):
    t = math.radians(deg)
    c, s = math.cos(t), math.sin(t)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def look_at_cv(centre, target):
    """OpenCV cam_from_world (x right, y down, z forward) for a camera at centre looking at
    target with world +z up."""
    z = target - centre
    z /= np.linalg.norm(z)
    x = np.cross(z, [0.0, 0.0, 1.0])
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    r = np.stack([x, y, z])
    m = np.eye(4)
    m[:3, :3] = r
    m[:3, 3] = -r @ centre
    return m


def sph(el, az):
    e, a = math.radians(el), math.radians(az)
    return np.array([math.cos(e) * math.cos(a), math.cos(e) * math.sin(a), math.sin(e)])


def read_obj(path):
    v, vt, vn, f = [], [], [], []
    with open(path) as fh:
        for line in fh:
            if line.startswith("v "):
                v.append([float(x) for x in line.split()[1:4]])
            elif line.startswith("vt "):
                vt.append([float(x) for x in line.split()[1:3]])
            elif line.startswith("vn "):
                vn.append([float(x) for x in line.split()[1:4]])
            elif line.startswith("f "):
                f.append([[int(i) - 1 for i in c.split("/")] for c in line.split()[1:]])
    f = np.array(f, dtype=np.int64)
    return np.array(v), np.array(vt), np.array(vn), f[:, :, 0], f[:, :, 1], f[:, :, 2]


def dilate(mask, r):
    out = mask.copy()
    for _ in range(r):
        m = out.copy()
        m[1:, :] |= out[:-1, :]
        m[:-1, :] |= out[1:, :]
        m[:, 1:] |= out[:, :-1]
        m[:, :-1] |= out[:, 1:]
        m[1:, 1:] |= out[:-1, :-1]
        m[1:, :-1] |= out[:-1, 1:]
        m[:-1, 1:] |= out[1:, :-1]
        m[:-1, :-1] |= out[1:, 1:]
        out = m
    return out


def extend_margin(values, known, rounds):
    """Fills unknown texels within `rounds` steps (8-neighbourhood) of the known ones with the
    mean of their known neighbours, one ring per round. values (H,W,C)."""
    values = values.copy()
    known = known.copy()
    h, w = known.shape
    for _ in range(rounds):
        pv = np.pad(values * known[..., None], ((1, 1), (1, 1), (0, 0)))
        pk = np.pad(known.astype(np.float64), 1)
        acc = np.zeros_like(values)
        cnt = np.zeros((h, w))
        for dy in (-1, 0, 1):
            for dx in (-1, 0, 1):
                if dy or dx:
                    acc += pv[1 + dy:1 + dy + h, 1 + dx:1 + dx + w]
                    cnt += pk[1 + dy:1 + dy + h, 1 + dx:1 + dx + w]
        new = (~known) & (cnt > 0)
        values[new] = acc[new] / cnt[new][:, None]
        known |= new
    return values, known


def bilinear(tex, uv):
    """tex (N,N,C) with row 0 = top (PNG order); uv per OBJ (v = 0 bottom), EXTEND."""
    n = tex.shape[0]
    x = uv[:, 0] * n - 0.5
    y = (1.0 - uv[:, 1]) * n - 0.5
    x0 = np.floor(x).astype(np.int64)
    y0 = np.floor(y).astype(np.int64)
    fx, fy = (x - x0)[:, None], (y - y0)[:, None]
    xa, xb = np.clip(x0, 0, n - 1), np.clip(x0 + 1, 0, n - 1)
    ya, yb = np.clip(y0, 0, n - 1), np.clip(y0 + 1, 0, n - 1)
    t = tex.astype(np.float64)
    return ((1 - fx) * (1 - fy) * t[ya, xa] + fx * (1 - fy) * t[ya, xb]
            + (1 - fx) * fy * t[yb, xa] + fx * fy * t[yb, xb])


# ----------------------------------------------------------------------------------------------
# Object.

def knot_mesh(n_u=360, n_v=36, p=2, q=3, tube=(0.66, 0.12), tilt_deg=25.0):
    """(p,q) torus-knot tube: centre line ((2+cos qt) cos pt, (2+cos qt) sin pt, -sin qt), a
    circular cross-section of radius tube[0] + tube[1] cos 2t in the Frenet frame. Tilted about
    x, scaled to OBJECT_SIZE, resting on z = 0, centred on the z axis. Returns vertices and quads.
    The varying thickness matters: a tube's largest curvature is 1/radius everywhere, so with a
    constant radius the whole surface falls on one side of a curvature threshold."""
    t = np.linspace(0.0, 2 * math.pi, n_u, endpoint=False)
    rad = tube[0] + tube[1] * np.cos(2 * t)
    r = 2.0 + np.cos(q * t)
    dr = -q * np.sin(q * t)
    ddr = -q * q * np.cos(q * t)
    cp, sp = np.cos(p * t), np.sin(p * t)
    c = np.stack([r * cp, r * sp, -np.sin(q * t)], 1)
    d1 = np.stack([dr * cp - p * r * sp, dr * sp + p * r * cp, -q * np.cos(q * t)], 1)
    d2 = np.stack([ddr * cp - 2 * p * dr * sp - p * p * r * cp,
                   ddr * sp + 2 * p * dr * cp - p * p * r * sp,
                   q * q * np.sin(q * t)], 1)
    T = d1 / np.linalg.norm(d1, axis=1, keepdims=True)
    N = d2 - (d2 * T).sum(1, keepdims=True) * T
    N /= np.linalg.norm(N, axis=1, keepdims=True)
    B = np.cross(T, N)
    a = np.linspace(0.0, 2 * math.pi, n_v, endpoint=False)
    verts = (c[:, None, :] + rad[:, None, None] * (np.cos(a)[None, :, None] * N[:, None, :]
                                     + np.sin(a)[None, :, None] * B[:, None, :]))
    verts = verts.reshape(-1, 3)
    tl = math.radians(tilt_deg)
    rx = np.array([[1, 0, 0], [0, math.cos(tl), -math.sin(tl)], [0, math.sin(tl), math.cos(tl)]])
    verts = verts @ rx.T
    lo, hi = verts.min(0), verts.max(0)
    verts = verts * (OBJECT_SIZE / (hi - lo).max())
    lo, hi = verts.min(0), verts.max(0)
    verts -= np.array([(lo[0] + hi[0]) / 2, (lo[1] + hi[1]) / 2, lo[2]])
    faces = []
    for i in range(n_u):
        i1 = (i + 1) % n_u
        for j in range(n_v):
            j1 = (j + 1) % n_v
            faces.append((i * n_v + j, i1 * n_v + j, i1 * n_v + j1, i * n_v + j1))
    return verts, faces


# Teapot: a Utah-teapot-like shape made of three closed parts (profile units: body radius 2).
# Body and lid are one surface of revolution of the profile below, (r, z) from the bottom pole to
# the top pole: flat base, rounded base edge, belly, shoulder, rim with an outward lip, a groove
# between the rim and the lid, domed lid, knob on a neck.
TEAPOT_PROFILE = [
    (0.00, 0.00), (0.70, 0.00), (1.25, 0.00), (1.45, 0.02), (1.56, 0.10), (1.72, 0.32),
    (1.90, 0.70), (2.00, 1.10), (1.95, 1.50), (1.80, 1.88), (1.60, 2.15), (1.47, 2.30),
    (1.49, 2.38), (1.54, 2.43), (1.49, 2.48), (1.36, 2.46), (1.30, 2.50), (1.10, 2.60),
    (0.75, 2.70), (0.40, 2.76), (0.22, 2.80), (0.17, 2.86), (0.26, 2.93), (0.37, 3.00),
    (0.36, 3.08), (0.24, 3.15), (0.10, 3.18), (0.00, 3.185)]
# Handle: a C-shaped centre line in the xz plane (y = 0), elliptic section (0.13 in the plane,
# 0.21 across it). Spout: an S-shaped centre line, circular section tapering from 0.44 to 0.16
# with a slight flare at the tip. Both start and end inside the body.
TEAPOT_HANDLE = [(-1.45, 2.02), (-1.90, 2.16), (-2.45, 2.20), (-2.85, 1.98), (-3.00, 1.55),
                 (-2.88, 1.12), (-2.50, 0.80), (-2.05, 0.62), (-1.55, 0.55)]
TEAPOT_SPOUT = [(1.15, 0.70), (1.75, 0.78), (2.25, 1.05), (2.55, 1.55), (2.78, 2.10),
                (3.02, 2.45), (3.22, 2.62)]


def catmull_rom(points, samples_per_segment=40):
    """Centripetal Catmull-Rom spline through the points (open curve, ends extrapolated)."""
    p = np.asarray(points, dtype=np.float64)
    p = np.vstack([2 * p[0] - p[1], p, 2 * p[-1] - p[-2]])
    out = []
    for i in range(1, len(p) - 2):
        p0, p1, p2, p3 = p[i - 1], p[i], p[i + 1], p[i + 2]
        t0 = 0.0
        t1 = t0 + np.linalg.norm(p1 - p0) ** 0.5
        t2 = t1 + np.linalg.norm(p2 - p1) ** 0.5
        t3 = t2 + np.linalg.norm(p3 - p2) ** 0.5
        t = np.linspace(t1, t2, samples_per_segment, endpoint=False)[:, None]
        a1 = (t1 - t) / (t1 - t0) * p0 + (t - t0) / (t1 - t0) * p1
        a2 = (t2 - t) / (t2 - t1) * p1 + (t - t1) / (t2 - t1) * p2
        a3 = (t3 - t) / (t3 - t2) * p2 + (t - t2) / (t3 - t2) * p3
        b1 = (t2 - t) / (t2 - t0) * a1 + (t - t0) / (t2 - t0) * a2
        b2 = (t3 - t) / (t3 - t1) * a2 + (t - t1) / (t3 - t1) * a3
        out.append((t2 - t) / (t2 - t1) * b1 + (t - t1) / (t2 - t1) * b2)
    out.append(p[-2][None])
    return np.vstack(out)


def resample_curve(dense, n, turn_weight=0.0):
    """n points along a polyline, evenly spaced in arc length + turn_weight * turning angle
    (so that sharp features get more points)."""
    seg = np.diff(dense, axis=0)
    length = np.linalg.norm(seg, axis=1)
    d = seg / np.maximum(length, 1e-12)[:, None]
    turn = np.zeros(len(seg))
    turn[1:] = np.arccos(np.clip((d[1:] * d[:-1]).sum(1), -1, 1))
    measure = np.concatenate([[0.0], np.cumsum(length + turn_weight * turn)])
    s = np.linspace(0.0, measure[-1], n)
    return np.stack([np.interp(s, measure, dense[:, k]) for k in range(dense.shape[1])], 1)


def tube_mesh(centre, radius_n, radius_b, n_around):
    """Closed tube along a centre line in the xz plane: sections in the (in-plane normal, y)
    frame with semi-axes radius_n, radius_b (arrays per centre point), both ends capped by a
    triangle fan. Returns vertices (3D) and faces."""
    c3 = np.stack([centre[:, 0], np.zeros(len(centre)), centre[:, 1]], 1)
    tan = np.gradient(c3, axis=0)
    tan /= np.linalg.norm(tan, axis=1, keepdims=True)
    nrm = np.cross(tan, [0.0, 1.0, 0.0])
    nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
    bin_ = np.array([0.0, 1.0, 0.0])
    a = np.linspace(0.0, 2 * math.pi, n_around, endpoint=False)
    ring = (c3[:, None, :] + radius_n[:, None, None] * np.cos(a)[None, :, None] * nrm[:, None, :]
            + radius_b[:, None, None] * np.sin(a)[None, :, None] * bin_[None, None, :])
    n_c = len(centre)
    verts = np.vstack([ring.reshape(-1, 3), c3[0], c3[-1]])
    first, last = n_c * n_around, n_c * n_around + 1
    faces = []
    for i in range(n_c - 1):
        for j in range(n_around):
            j1 = (j + 1) % n_around
            faces.append((i * n_around + j, (i + 1) * n_around + j,
                          (i + 1) * n_around + j1, i * n_around + j1))
    for j in range(n_around):
        j1 = (j + 1) % n_around
        faces.append((first, j1, j))
        faces.append((last, (n_c - 1) * n_around + j, (n_c - 1) * n_around + j1))
    return verts, faces


def teapot_parts(n_around=96, n_profile=110, n_handle=64, n_handle_around=16, n_spout=64,
                 n_spout_around=24):
    """The teapot's three closed parts in profile units: [(name, vertices, faces)]."""
    prof = resample_curve(catmull_rom(TEAPOT_PROFILE, 60), n_profile, turn_weight=0.25)
    prof[0] = (0.0, prof[0, 1])
    prof[-1] = (0.0, prof[-1, 1])
    a = np.linspace(0.0, 2 * math.pi, n_around, endpoint=False)
    inner = prof[1:-1]
    ring = np.stack([inner[:, None, 0] * np.cos(a)[None, :], inner[:, None, 0] * np.sin(a)[None, :],
                     np.repeat(inner[:, 1:2], n_around, 1)], 2).reshape(-1, 3)
    bottom, top = len(ring), len(ring) + 1
    body_v = np.vstack([ring, [0.0, 0.0, prof[0, 1]], [0.0, 0.0, prof[-1, 1]]])
    body_f = []
    n_r = len(inner)
    for i in range(n_r - 1):
        for j in range(n_around):
            j1 = (j + 1) % n_around
            body_f.append((i * n_around + j, i * n_around + j1, (i + 1) * n_around + j1,
                           (i + 1) * n_around + j))
    for j in range(n_around):
        j1 = (j + 1) % n_around
        body_f.append((bottom, j1, j))
        body_f.append((top, (n_r - 1) * n_around + j, (n_r - 1) * n_around + j1))
    hc = resample_curve(catmull_rom(TEAPOT_HANDLE, 40), n_handle)
    handle_v, handle_f = tube_mesh(hc, np.full(n_handle, 0.13), np.full(n_handle, 0.21),
                                   n_handle_around)
    sc = resample_curve(catmull_rom(TEAPOT_SPOUT, 40), n_spout)
    u = np.linspace(0.0, 1.0, n_spout)
    sr = 0.44 - 0.30 * u ** 0.8 + 0.05 * np.clip((u - 0.88) / 0.12, 0, 1) ** 2
    spout_v, spout_f = tube_mesh(sc, sr, sr, n_spout_around)
    return [("body", body_v, body_f), ("handle", handle_v, handle_f),
            ("spout", spout_v, spout_f)]


def mesh_object(name, verts, faces):
    mesh = bpy.data.meshes.new(name)
    mesh.from_pydata([tuple(v) for v in verts], [], faces)
    bm = bmesh.new()
    bm.from_mesh(mesh)
    bmesh.ops.recalc_face_normals(bm, faces=bm.faces[:])
    bm.to_mesh(mesh)
    bm.free()
    obj = bpy.data.objects.new(name, mesh)
    bpy.context.scene.collection.objects.link(obj)
    return obj


def teapot_object():
    """Body, handle and spout joined by Blender's exact boolean union into one closed mesh,
    scaled to OBJECTS["teapot"]["size"] largest side, resting on z = 0, bounding box centred on the z axis."""
    parts = teapot_parts()
    allv = np.vstack([v for _, v, _ in parts])
    scale = OBJECTS["teapot"]["size"] / (allv.max(0) - allv.min(0)).max()
    objs = [mesh_object("teapot_" + n, v * scale, f) for n, v, f in parts]
    body = objs[0]
    for other in objs[1:]:
        mod = body.modifiers.new("union_" + other.name, "BOOLEAN")
        mod.operation = "UNION"
        mod.solver = "EXACT"
        mod.object = other
    dg = bpy.context.evaluated_depsgraph_get()
    mesh = bpy.data.meshes.new_from_object(body.evaluated_get(dg))
    mesh.name = "teapot"
    for o in objs:
        m = o.data
        bpy.data.objects.remove(o)
        bpy.data.meshes.remove(m)
    info = {"profile_units_to_m": float(scale),
            "parts": {n: {"vertices": int(len(v)), "faces": len(f)} for n, v, f in parts}}
    return mesh, info


def build_object(name, uv_angle):
    """The object, triangulated, smooth shaded, with a Smart UV Project atlas, and a dict of
    facts about it for capture.json."""
    info = {}
    if name == "knot":
        verts, faces = knot_mesh()
        mesh = bpy.data.meshes.new("knot")
        mesh.from_pydata([tuple(v) for v in verts], [], faces)
    elif name == "teapot":
        mesh, info = teapot_object()
    else:
        raise SystemExit("unknown --object %r (supported: %s)" % (name, ", ".join(OBJECTS)))
    bm = bmesh.new()
    bm.from_mesh(mesh)
    if name == "teapot":
        bmesh.ops.remove_doubles(bm, verts=bm.verts[:], dist=1e-7)
        bmesh.ops.dissolve_degenerate(bm, dist=1e-8, edges=bm.edges[:])
    bmesh.ops.recalc_face_normals(bm, faces=bm.faces[:])
    bmesh.ops.triangulate(bm, faces=bm.faces[:], quad_method="BEAUTY", ngon_method="BEAUTY")
    for f in bm.faces:
        f.smooth = True
    if name == "teapot":
        # Rest on z = 0 with the bounding box centred on the turntable axis.
        co = np.array([v.co[:] for v in bm.verts])
        lo, hi = co.min(0), co.max(0)
        shift = Vector((-(lo[0] + hi[0]) / 2, -(lo[1] + hi[1]) / 2, -lo[2]))
        for v in bm.verts:
            v.co += shift
        info["shift_m"] = list(shift)
        non_manifold = sum(1 for e in bm.edges if len(e.link_faces) != 2)
        info["non_manifold_edges"] = non_manifold
        info["boundary_edges"] = sum(1 for e in bm.edges if len(e.link_faces) < 2)
        if non_manifold:
            print("WARNING: teapot union has %d non-manifold edges" % non_manifold, flush=True)
    bm.to_mesh(mesh)
    bm.free()
    if name == "teapot":
        # Split normals at creases sharper than 60 deg (the seams where the handle and spout
        # meet the body, the spout's end cap); mesh.obj carries the same per-corner normals.
        mesh.use_auto_smooth = True
        mesh.auto_smooth_angle = math.radians(60.0)
    obj = bpy.data.objects.new(name, mesh)
    bpy.context.scene.collection.objects.link(obj)
    obj.rotation_mode = "XYZ"
    # Smart UV Project.
    bpy.context.view_layer.objects.active = obj
    obj.select_set(True)
    bpy.ops.object.mode_set(mode="EDIT")
    bpy.ops.mesh.select_all(action="SELECT")
    bpy.ops.uv.smart_project(angle_limit=math.radians(uv_angle), margin_method="FRACTION",
                             island_margin=0.008, area_weight=0.0, correct_aspect=True,
                             scale_to_bounds=False)
    bpy.ops.object.mode_set(mode="OBJECT")
    return obj, info


OBJECTS = {
    # own rig, Voronoi base-colour patches, roughness regions
    "knot": {"rig": "knot", "size": OBJECT_SIZE, "n_colour": 30, "n_rough": 12},
    # 0.21 m (spout tip to handle): with suzanne's fx the bounding box spans 38-64 % of the
    # frame width (suzanne: 43-63 %); the narrow views look along the spout.
    "teapot": {"rig": "suzanne", "size": 0.21, "n_colour": 36, "n_rough": 14},
}


def mesh_arrays(obj):
    me = obj.data
    me.calc_normals_split()
    nv, nl, nf = len(me.vertices), len(me.loops), len(me.polygons)
    v = np.empty(nv * 3)
    me.vertices.foreach_get("co", v)
    lv = np.empty(nl, dtype=np.int64)
    me.loops.foreach_get("vertex_index", lv)
    ln = np.empty(nl * 3)
    me.loops.foreach_get("normal", ln)
    uv = np.empty(nl * 2)
    me.uv_layers.active.data.foreach_get("uv", uv)
    ls = np.empty(nf, dtype=np.int64)
    me.polygons.foreach_get("loop_start", ls)
    tot = np.empty(nf, dtype=np.int64)
    me.polygons.foreach_get("loop_total", tot)
    assert (tot == 3).all()
    corners = ls[:, None] + np.arange(3)[None, :]
    return v.reshape(-1, 3), lv, ln.reshape(-1, 3), uv.reshape(-1, 2), corners


OBJ_TITLES = {"knot": "(2,3) torus-knot tube",
              "teapot": "teapot (body of revolution + lid + knob, handle, spout; boolean union)"}


def write_obj(path, obj, name):
    v, lv, ln, uv, corners = mesh_arrays(obj)
    lines = ["# %s: %s, object frame (metres, z up), triangulated" % (name, OBJ_TITLES[name]),
             "# written by bench/blender/turntable_capture.py", "o " + name]
    lines += ["v %.7f %.7f %.7f" % tuple(p) for p in v]
    uv_keys, uv_idx = np.unique(np.round(uv, 7), axis=0, return_inverse=True)
    n_keys, n_idx = np.unique(np.round(ln, 6), axis=0, return_inverse=True)
    uv_idx, n_idx = uv_idx.ravel(), n_idx.ravel()
    lines += ["vt %.7f %.7f" % tuple(t) for t in uv_keys]
    lines += ["vn %.6f %.6f %.6f" % tuple(n) for n in n_keys]
    for tri in corners:
        lines.append("f " + " ".join("%d/%d/%d" % (lv[k] + 1, uv_idx[k] + 1, n_idx[k] + 1)
                                     for k in tri))
    with open(path, "w") as fh:
        fh.write("\n".join(lines) + "\n")
    return v, lv, ln, uv, corners


# ----------------------------------------------------------------------------------------------
# Ground-truth textures: 3D Voronoi patches on the surface, baked through texel positions.

def node_material(name):
    """A new material with an empty node tree but its output node: (material, tree, output)."""
    mat = bpy.data.materials.new(name)
    mat.use_nodes = True
    nt = mat.node_tree
    nt.nodes.clear()
    return mat, nt, nt.nodes.new("ShaderNodeOutputMaterial")


def bake_texel_positions(obj, lo, ext):
    """Bakes each texel's object-frame position (EMIT of normalised Object coordinates) and a
    coverage mask (EMIT of white), both without margin."""
    mat, nt, out = node_material("bake")
    emi = nt.nodes.new("ShaderNodeEmission")
    tc = nt.nodes.new("ShaderNodeTexCoord")
    sub = nt.nodes.new("ShaderNodeVectorMath")
    sub.operation = "SUBTRACT"
    sub.inputs[1].default_value = tuple(lo)
    div = nt.nodes.new("ShaderNodeVectorMath")
    div.operation = "DIVIDE"
    div.inputs[1].default_value = tuple(ext)
    nt.links.new(tc.outputs["Object"], sub.inputs[0])
    nt.links.new(sub.outputs[0], div.inputs[0])
    nt.links.new(div.outputs[0], emi.inputs["Color"])
    emi.inputs["Strength"].default_value = 1.0
    nt.links.new(emi.outputs[0], out.inputs["Surface"])
    tex = nt.nodes.new("ShaderNodeTexImage")
    obj.data.materials.clear()
    obj.data.materials.append(mat)
    scene = bpy.context.scene
    spp = scene.cycles.samples
    scene.cycles.samples = 4
    res = {}
    for key, margin, white in (("pos", 0, False), ("cov", 0, True)):
        img = bpy.data.images.new("bake_" + key, TEX_RES, TEX_RES, alpha=True, float_buffer=True)
        img.colorspace_settings.name = "Non-Color"
        tex.image = img
        nt.nodes.active = tex
        if white:
            nt.links.remove(emi.inputs["Color"].links[0])
            emi.inputs["Color"].default_value = (1, 1, 1, 1)
        bpy.ops.object.bake(type="EMIT", margin=margin, margin_type="EXTEND", use_clear=True)
        px = np.empty(TEX_RES * TEX_RES * 4, dtype=np.float32)
        img.pixels.foreach_get(px)
        res[key] = px.reshape(TEX_RES, TEX_RES, 4)[::-1].astype(np.float64)  # row 0 = top
        bpy.data.images.remove(img)
    obj.data.materials.clear()
    bpy.data.materials.remove(mat)
    scene.cycles.samples = spp
    pos = res["pos"][..., :3] * ext + lo
    covered = res["cov"][..., 0] > 0.5
    return pos, covered


def farthest_points(points, n, rng):
    idx = [int(rng.integers(len(points)))]
    d = np.linalg.norm(points - points[idx[0]], axis=1)
    for _ in range(n - 1):
        i = int(np.argmax(d))
        idx.append(i)
        d = np.minimum(d, np.linalg.norm(points - points[i], axis=1))
    return points[idx]


def make_textures(obj, verts, out_dir, rng, n_colour=30, n_rough=12):
    lo, hi = verts.min(0) - 1e-3, verts.max(0) + 1e-3
    pos, covered = bake_texel_positions(obj, lo, hi - lo)
    # Seeds spread over the surface (farthest-point sampling of the vertices, random start).
    cseeds = farthest_points(verts, n_colour, rng)
    rseeds = farthest_points(verts, n_rough, rng)
    pal = srgb_to_linear(np.array(PALETTE_SRGB) / 255.0)
    pal = 0.02 + pal * (0.70 / pal.max())          # linear albedo in [0.02, 0.72]
    order = np.concatenate([rng.permutation(len(pal)) for _ in range(n_colour // len(pal) + 1)])
    patch_lin = pal[order[:n_colour]] * rng.uniform(0.92, 1.08, size=(n_colour, 1))
    glossy = rng.permutation(np.arange(n_rough) % 2 == 0)
    rvals = np.where(glossy, rng.uniform(0.15, 0.30, n_rough), rng.uniform(0.55, 0.85, n_rough))
    # Low-frequency +-10 % modulation: three plane waves of ~0.1 m wavelength.
    dirs = rng.normal(size=(3, 3))
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    phases = rng.uniform(0, 2 * math.pi, 3)

    p = pos[covered]
    cid = np.argmin(((p[:, None, :] - cseeds[None]) ** 2).sum(2), axis=1)
    rid = np.argmin(((p[:, None, :] - rseeds[None]) ** 2).sum(2), axis=1)
    wave = np.sin(2 * math.pi * (p @ dirs.T) / 0.10 + phases).sum(1) / 3.0
    mod = 1.0 + 0.10 * wave / max(1e-9, np.abs(wave).max())
    albedo = np.clip(patch_lin[cid] * mod[:, None], 0.0, 0.9)
    vals = np.zeros((TEX_RES, TEX_RES, 4))
    vals[covered, :3] = albedo
    vals[covered, 3] = rvals[rid]
    vals, filled = extend_margin(vals, covered, BAKE_MARGIN)    # islands + margin
    vals[~filled, :3] = np.median(albedo, axis=0)
    vals[~filled, 3] = 0.5
    base, rough = vals[..., :3], vals[..., 3]
    base8 = np.round(linear_to_srgb(base) * 255.0).astype(np.uint8)
    rough8 = np.round(rough * 255.0).astype(np.uint8)
    write_png(os.path.join(out_dir, "gt_basecolor.png"), base8)
    write_png(os.path.join(out_dir, "gt_roughness.png"), rough8)
    cov_cid = np.zeros((TEX_RES, TEX_RES), np.int64) - 1
    cov_cid[covered] = cid
    stats = {
        "texels_covered_fraction": float(covered.mean()),
        "texels_with_margin_fraction": float(filled.mean()),
        "basecolor_patches": int(len(np.unique(cov_cid[covered]))),
        "roughness_regions": int(len(np.unique(rid))),
        "roughness_region_values": [round(float(x), 4) for x in rvals],
        "roughness_region_glossy": [bool(g) for g in glossy],
        "glossy_fraction_of_covered_texels": float((rough8[covered] < 128).mean()),
        "basecolor_patch_linear_rgb": [[round(float(c), 4) for c in col] for col in patch_lin],
        "modulation": "albedo *= 1 + 0.10 * w(p)/max|w|, w = mean of 3 sin plane waves, "
                      "wavelength 0.10 m, random directions and phases",
    }
    return stats


def render_material(out_dir):
    mat, nt, out = node_material("principled_gt")
    bsdf = nt.nodes.new("ShaderNodeBsdfPrincipled")
    bsdf.distribution = "GGX"
    uvn = nt.nodes.new("ShaderNodeUVMap")
    imgs = {}
    for key, fname, cs in (("base", "gt_basecolor.png", "sRGB"),
                           ("rough", "gt_roughness.png", "Non-Color")):
        img = bpy.data.images.load(os.path.join(out_dir, fname), check_existing=False)
        img.colorspace_settings.name = cs
        node = nt.nodes.new("ShaderNodeTexImage")
        node.image = img
        node.interpolation = "Linear"
        node.extension = "EXTEND"
        nt.links.new(uvn.outputs["UV"], node.inputs["Vector"])
        imgs[key] = node
    nt.links.new(imgs["base"].outputs["Color"], bsdf.inputs["Base Color"])
    nt.links.new(imgs["rough"].outputs["Color"], bsdf.inputs["Roughness"])
    consts = {"Metallic": 0.0, "Specular": 0.5, "Specular Tint": 0.0, "Anisotropic": 0.0,
              "Sheen": 0.0, "Clearcoat": 0.0, "Transmission": 0.0, "Subsurface": 0.0,
              "IOR": 1.45}
    for k, val in consts.items():
        bsdf.inputs[k].default_value = val
    nt.links.new(bsdf.outputs["BSDF"], out.inputs["Surface"])
    return mat


# ----------------------------------------------------------------------------------------------
# Scene.

def setup_scene(res, spp):
    bpy.ops.wm.read_factory_settings(use_empty=True)
    scene = bpy.context.scene
    scene.render.engine = "CYCLES"
    cy = scene.cycles
    cy.device = "CPU"
    cy.samples = spp
    cy.use_adaptive_sampling = False
    cy.use_denoising = False
    cy.max_bounces = 12
    cy.diffuse_bounces = 4
    cy.glossy_bounces = 4
    cy.caustics_reflective = True
    cy.caustics_refractive = True
    cy.sample_clamp_direct = 0.0
    cy.sample_clamp_indirect = 10.0
    cy.blur_glossy = 1.0
    cy.pixel_filter_type = "BLACKMAN_HARRIS"
    cy.filter_width = 1.5
    cy.use_animated_seed = False
    scene.render.threads_mode = "FIXED"
    scene.render.threads = 2
    scene.render.use_persistent_data = True
    scene.render.resolution_x = res
    scene.render.resolution_y = res
    scene.render.resolution_percentage = 100
    scene.render.pixel_aspect_x = scene.render.pixel_aspect_y = 1.0
    scene.render.film_transparent = False
    scene.render.use_compositing = False
    scene.render.use_sequencer = False
    scene.view_settings.view_transform = "Standard"
    scene.view_settings.look = "None"
    scene.view_settings.exposure = 0.0
    scene.view_settings.gamma = 1.0
    ims = scene.render.image_settings
    ims.file_format = "OPEN_EXR"
    ims.color_mode = "RGB"
    ims.color_depth = "16"
    ims.exr_codec = "ZIP"
    world = bpy.data.worlds.new("black")
    world.use_nodes = True
    bg = world.node_tree.nodes["Background"]
    bg.inputs["Color"].default_value = (0, 0, 0, 1)
    bg.inputs["Strength"].default_value = 0.0
    scene.world = world
    return scene


def add_camera(name, cam_from_world, fx, res):
    data = bpy.data.cameras.new(name)
    data.type = "PERSP"
    data.sensor_fit = "HORIZONTAL"
    data.sensor_width = 36.0
    data.lens = fx * 36.0 / res
    data.shift_x = data.shift_y = 0.0    # principal point (res-1)/2 in OpenCV pixel-centre coords
    data.clip_start = 0.05
    data.clip_end = 10.0
    obj = bpy.data.objects.new(name, data)
    bpy.context.scene.collection.objects.link(obj)
    world_from_cv = np.linalg.inv(cam_from_world)
    flip = np.diag([1.0, -1.0, -1.0, 1.0])      # OpenCV camera axes -> Blender camera axes
    obj.matrix_world = Matrix((world_from_cv @ flip).tolist())
    return obj


def add_light(name, pos):
    data = bpy.data.lights.new(name, type="POINT")
    data.energy = LIGHT_POWER
    data.shadow_soft_size = LIGHT_RADIUS
    data.color = (1.0, 1.0, 1.0)
    obj = bpy.data.objects.new(name, data)
    obj.location = tuple(pos)
    obj.visible_camera = False
    bpy.context.scene.collection.objects.link(obj)
    return obj


# ----------------------------------------------------------------------------------------------
# Capture.

def object_description(name, tube_mm):
    if name == "knot":
        return ("(2,3) torus knot (trefoil) tube: centre line ((2+cos 3t) cos 2t, "
                "(2+cos 3t) sin 2t, -sin 3t), tube radius 0.66 + 0.12 cos 2t "
                "(same units; %.1f-%.1f mm after scaling), Frenet-frame "
                "circular sections, 360 x 36 quads, triangulated, tilted 25 deg "
                "about x, scaled to 0.2 m largest side, smooth shading" % tube_mm)
    return ("Utah-teapot-like shape: body and lid one surface of revolution (96 segments) of a "
            "Catmull-Rom profile (flat base, belly, shoulder, rim with a lip, groove, domed lid, "
            "knob on a neck); a C-shaped handle (elliptic swept tube, leaves a hole) and an "
            "S-shaped spout (tapered circular swept tube, flat end cap), both closed; joined "
            "by Blender's exact boolean union into one closed mesh, triangulated, smooth "
            "shading with normals split at creases > 60 deg (per-corner vn in mesh.obj), "
            "scaled to 0.21 m largest side (spout tip to handle), resting on z = 0, bounding "
            "box centred on the turntable axis")


def capture(args):
    t_start = time.time()
    out = os.path.abspath(args.out)
    for sub in ("images", "masks", "checks"):
        os.makedirs(os.path.join(out, sub), exist_ok=True)
    rng = np.random.default_rng(args.seed)
    scene = setup_scene(args.res, args.spp)
    if args.object not in OBJECTS:
        raise SystemExit("unknown --object %r (supported: %s)" % (args.object, ", ".join(OBJECTS)))
    spec = OBJECTS[args.object]
    rig_name = args.rig or spec["rig"]
    rig = RIGS[rig_name]
    CAM_EL, CAM_AZ, CAM_DIST = rig["cam_el"], rig["cam_az"], rig["cam_dist"]
    LIGHT_EL, LIGHT_AZ = rig["light_el"], rig["light_az"]
    HOLDOUT_ANGLES, HOLDOUT_LIGHTS = rig["holdout_angles"], rig["holdout_lights"]
    obj, obj_info = build_object(args.object, args.uv_angle)

    v, lv, ln, uv, corners = write_obj(os.path.join(out, "mesh.obj"), obj, args.object)
    ov, ovt, ovn, ofv, oft, ofn = read_obj(os.path.join(out, "mesh.obj"))
    export_check = {
        "obj_vertices": int(len(ov)), "obj_triangles": int(len(ofv)),
        "same_triangle_order": bool((ofv == lv[corners]).all()),
        "max_abs_vertex_diff_m": float(np.abs(ov - v).max()),
        "max_abs_uv_diff": float(np.abs(ovt[oft] - uv[corners]).max()),
        "max_abs_normal_diff": float(np.abs(ovn[ofn] - ln[corners]).max())}
    lo, hi = v.min(0), v.max(0)
    centre = np.array([0.0, 0.0, (lo[2] + hi[2]) / 2])
    if args.object == "knot":
        kv, _ = knot_mesh()
        ring = np.linalg.norm(kv.reshape(360, 36, 3) - kv.reshape(360, 36, 3).mean(1, keepdims=True),
                              axis=2).mean(1)
        tube_mm = (1000 * ring.min(), 1000 * ring.max())
    tris = [tuple(x) for x in lv[corners].tolist()]
    bvh = BVHTree.FromPolygons([tuple(p) for p in v], tris, all_triangles=True)
    self_hits = [(i, j) for i, j in bvh.overlap(bvh)
                 if i < j and not set(tris[i]) & set(tris[j])]
    if self_hits:
        print("WARNING: %d intersecting triangle pairs" % len(self_hits), flush=True)
    tex_stats = make_textures(obj, v, out, rng, spec["n_colour"], spec["n_rough"])
    uvp = np.stack([uv[:, 0] * 2048 - 0.5, (1 - uv[:, 1]) * 2048 - 0.5], 1)
    pix, _, _ = rasterize(uvp, np.arange(len(uv)).reshape(-1, 3), 2048, 2048)
    tex_stats["uv_overlapping_texels_at_2048"] = int((np.bincount(pix) > 1).sum())
    if tex_stats["uv_overlapping_texels_at_2048"]:
        print("WARNING: UV islands overlap in %d texels at 2048^2 (try another --uv-angle)"
              % tex_stats["uv_overlapping_texels_at_2048"], flush=True)
    mat = render_material(out)
    obj.data.materials.append(mat)
    t_setup = time.time() - t_start

    # Cameras: the rig's fx, or one so that the object's projected bounding box spans the rig's
    # target_span of the frame (averaged over the views).
    poses = [look_at_cv(centre + CAM_DIST * sph(el, CAM_AZ), centre) for el in CAM_EL]
    spans1 = []
    for m in poses:
        for ang in ANGLES:
            pc = (v @ rot_z(ang).T) @ m[:3, :3].T + m[:3, 3]
            x = pc[:, 0] / pc[:, 2]
            spans1.append(x.max() - x.min())
    if rig["fx"] is not None:
        fx = rig["fx"] * args.res / 320.0
    else:
        fx = round(rig["target_span"] * args.res / float(np.mean(spans1)), 2)
    cx = cy = (args.res - 1) / 2.0
    K = [[fx, 0.0, cx], [0.0, fx, cy], [0.0, 0.0, 1.0]]
    cams = [add_camera("cam%d" % i, m, fx, args.res) for i, m in enumerate(poses)]
    light_defs = []
    for el in LIGHT_EL:
        for az in LIGHT_AZ:
            light_defs.append((el, az, centre + LIGHT_DIST * sph(el, az)))
    lights = [add_light("L%d" % i, p) for i, (_, _, p) in enumerate(light_defs)]
    intensity = LIGHT_POWER / (4 * math.pi)

    images = []
    idx = 0
    for ang in ANGLES:
        for ci in range(len(cams)):
            for li in range(len(lights)):
                hold = (ang in HOLDOUT_ANGLES) or \
                       ("L%d" % li) in HOLDOUT_LIGHTS
                images.append({"file": "images/%04d.exr" % idx, "camera": "cam%d" % ci,
                               "light": "L%d" % li, "turntable_deg": ang, "exposure_s": 1.0,
                               "split": "holdout" if hold else "train"})
                idx += 1

    # Photographs.
    assert scene.cycles.samples == args.spp and scene.cycles.filter_width == 1.5
    log = []
    t_render0 = time.time()
    if not args.skip_render:
        idx = 0
        for ang in ANGLES:
            obj.rotation_euler = (0.0, 0.0, math.radians(ang))
            for ci, cam in enumerate(cams):
                scene.camera = cam
                for li in range(len(lights)):
                    if args.limit and idx >= args.limit:
                        break
                    if args.only_split and images[idx]["split"] != args.only_split:
                        idx += 1
                        continue
                    for lj, lo_ in enumerate(lights):
                        lo_.hide_render = lj != li
                    scene.cycles.seed = 1000 * args.seed + args.noise_seed_offset + idx
                    scene.render.filepath = os.path.join(out, images[idx]["file"])
                    t0 = time.time()
                    bpy.ops.render.render(write_still=True)
                    log.append({"image": idx, "seconds": round(time.time() - t0, 3)})
                    if idx % 24 == 0:
                        print("render %d/%d %.2fs" % (idx, len(images), time.time() - t0),
                              flush=True)
                    idx += 1
    t_render = time.time() - t_render0

    # Masks: emission override, no lights, one ray through each pixel centre.
    t_mask0 = time.time()
    emat, en, eo = node_material("mask_emission")
    ee = en.nodes.new("ShaderNodeEmission")
    ee.inputs["Color"].default_value = (1, 1, 1, 1)
    ee.inputs["Strength"].default_value = 1.0
    en.links.new(ee.outputs[0], eo.inputs["Surface"])
    bpy.context.view_layer.material_override = emat
    for lo_ in lights:
        lo_.hide_render = True
    scene.cycles.samples = 1
    scene.cycles.filter_width = 0.01
    scene.cycles.max_bounces = 0
    scene.render.image_settings.color_depth = "32"
    tmp = os.path.join(out, "checks", "_mask_tmp.exr")
    for ang in ANGLES:
        obj.rotation_euler = (0.0, 0.0, math.radians(ang))
        for ci, cam in enumerate(cams):
            scene.camera = cam
            scene.render.filepath = tmp
            bpy.ops.render.render(write_still=True)
            m = read_exr(tmp)[..., 0] > 0.5
            write_png(os.path.join(out, "masks", "cam%d_%03d.png" % (ci, int(ang))),
                      np.where(m, 255, 0).astype(np.uint8))
    os.remove(tmp)
    bpy.context.view_layer.material_override = None
    t_mask = time.time() - t_mask0

    n_hold = sum(im["split"] == "holdout" for im in images)
    cap = {
        "format": "capture/1",
        "mesh": "mesh.obj",
        "cameras": [{"id": "cam%d" % i, "width": args.res, "height": args.res, "K": K,
                     "dist": [0.0] * 5, "cam_from_world": m.tolist()}
                    for i, m in enumerate(poses)],
        "lights": [{"id": "L%d" % i, "type": "point", "position": [float(x) for x in p],
                    "intensity": [intensity] * 3} for i, (_, _, p) in enumerate(light_defs)],
        "turntable": {"axis": [0.0, 0.0, 1.0], "point": [0.0, 0.0, 0.0]},
        "images": images,
        "ground_truth": {
            "note": "Synthetic photographs rendered with Blender Cycles (path tracing with global "
                    "illumination) by bench/blender/turntable_capture.py. The reflectance is "
                    "Blender's Principled BSDF (v1: GGX specular + Disney-style diffuse), NOT "
                    "Lambert+Lafortune; a Lambert+Lafortune fit can only approximate it.",
            "renderer": {
                "blender_version": bpy.app.version_string, "engine": "Cycles (CPU)",
                "spp": args.spp, "adaptive_sampling": False, "denoiser": None,
                "bounces": {"max": 12, "diffuse": 4, "glossy": 4},
                "caustics": {"reflective": True, "refractive": True},
                "clamp_direct": 0.0, "clamp_indirect": 10.0, "blur_glossy": 1.0,
                "pixel_filter": "BLACKMAN_HARRIS 1.50 px",
                "view_transform": "Standard, look None, exposure 0, gamma 1 (EXR holds "
                                  "scene-linear values, Rec.709 primaries)",
                "world": "black, strength 0", "threads": 2,
                "output": "OpenEXR half float RGB, ZIP",
                "noise_seed": "Cycles seed = 1000*seed + image index",
            },
            "textures": {
                "uv_convention": "OBJ vt; v = 0 is the bottom row of the PNG, v = 1 its top; "
                                 "texel centres at ((i+0.5)/N, (j+0.5)/N); the renderer samples "
                                 "them bilinearly (Blender 'Linear', EXTEND)",
                "basecolor": {"file": "gt_basecolor.png", "size": TEX_RES,
                              "meaning": "Principled BSDF 'Base Color' (diffuse albedo of the "
                                         "dielectric)",
                              "encoding": "8-bit RGB, sRGB-encoded (IEC 61966-2-1); Blender colour "
                                          "space 'sRGB'; linear albedo = srgb_to_linear(byte/255)"},
                "roughness": {"file": "gt_roughness.png", "size": TEX_RES,
                              "meaning": "Principled BSDF 'Roughness' r; GGX alpha = r^2",
                              "encoding": "8-bit grey, linear: r = byte/255; Blender colour space "
                                          "'Non-Color'"},
                "pattern": "3D Voronoi cells (nearest of %d / %d seed points spread over the "
                           "surface by farthest-point sampling), evaluated at each texel's "
                           "baked object-frame position (Cycles EMIT bake of the Object "
                           "coordinates, no margin); dilated by %d texels past the UV "
                           "islands (each ring the mean of its filled 8-neighbours); texels "
                           "further out hold the median albedo and roughness 0.5"
                           % (spec["n_colour"], spec["n_rough"], BAKE_MARGIN),
                "palette_srgb": [list(c) for c in PALETTE_SRGB],
                "stats": tex_stats,
            },
            "principled_constants": {
                "metallic": 0.0, "specular": 0.5, "specular_F0": 0.04, "specular_tint": 0.0,
                "subsurface": 0.0, "anisotropic": 0.0, "sheen": 0.0, "clearcoat": 0.0,
                "transmission": 0.0, "ior": 1.45, "distribution": "GGX"},
            "object": {
                "kind": args.object,
                "description": object_description(args.object, tube_mm if args.object == "knot"
                                                  else None),
                "build": obj_info,
                "material_seed": args.seed,
                "vertices": int(len(v)), "triangles": int(len(corners)),
                "self_intersecting_triangle_pairs": len(self_hits),
                "bbox_min": lo.tolist(), "bbox_max": hi.tolist(),
                "uv": {"method": "Smart UV Project", "angle_limit_deg": args.uv_angle,
                       "island_margin_fraction": 0.008,
                       "overlapping_texels_at_2048": tex_stats["uv_overlapping_texels_at_2048"],
                       "covered_fraction_at_1024": tex_stats["texels_covered_fraction"]},
            },
            "mesh_export_check": export_check,
            "lights": {"blender_power_W": LIGHT_POWER, "radius_m": LIGHT_RADIUS,
                       "colour": [1, 1, 1], "intensity_W_per_sr": intensity,
                       "intensity_rule": "I = P / (4 pi) (the suzanne capture's calibration of "
                                         "the same Blender version gives I/P = 0.079576)"},
            "rig": {
                "name": rig_name,
                "cam_el": CAM_EL, "cam_az": CAM_AZ, "cam_dist": CAM_DIST, "fx": fx,
                "light_el": LIGHT_EL, "light_az": LIGHT_AZ, "light_dist": LIGHT_DIST,
                "angles": ANGLES, "camera_target": centre.tolist(),
                "holdout_angles": HOLDOUT_ANGLES, "holdout_lights": HOLDOUT_LIGHTS,
                "light_ids": {"L%d" % i: {"elevation_deg": el, "azimuth_deg": az}
                              for i, (el, az, _) in enumerate(light_defs)},
                "camera_ids": {"cam%d" % i: {"elevation_deg": el, "azimuth_deg": CAM_AZ}
                               for i, el in enumerate(CAM_EL)},
                "azimuth_convention": "degrees from world +x towards +y; elevation above the "
                                      "z = target plane",
                "object_bbox_over_frame_width": {
                    "min": float(np.min(spans1) * fx / args.res),
                    "mean": float(np.mean(spans1) * fx / args.res),
                    "max": float(np.max(spans1) * fx / args.res)},
            },
            "splits": {"rule": "holdout = turntable angle in %s (those angles, not the interval "
                               "between them) OR light %s (elevation %g, azimuth %g)"
                               % (HOLDOUT_ANGLES, HOLDOUT_LIGHTS,
                                  light_defs[int(HOLDOUT_LIGHTS[0][1:])][0],
                                  light_defs[int(HOLDOUT_LIGHTS[0][1:])][1]),
                       "train": len(images) - n_hold, "holdout": n_hold},
            "masks": {
                "files": "masks/{camera}_{turntable_deg:03d}.png, e.g. masks/cam0_030.png",
                "encoding": "8-bit grey PNG, 255 = object, 0 = background",
                "definition": "255 iff the camera ray through the pixel centre hits the object "
                              "posed at that angle. Silhouette-fringe pixels that the photos' "
                              "1.5 px filter makes partly lit can be 0.",
                "made_by": "Cycles, emission-only material override, no lights, 1 sample, "
                           "Blackman-Harris filter width 0.01 px, thresholded at 0.5",
            },
        },
    }
    with open(os.path.join(out, "capture.json"), "w") as fh:
        json.dump(cap, fh, indent=1)
    timing = {"setup_s": round(t_setup, 1), "render_s": round(t_render, 1),
              "per_image_s": round(t_render / max(1, len(log)), 3), "masks_s": round(t_mask, 1),
              "total_s": round(time.time() - t_start, 1), "images": len(log)}
    with open(os.path.join(out, "checks", "render_log.json"), "w") as fh:
        json.dump({"timing": timing, "per_image": log}, fh)
    print("CAPTURE DONE", json.dumps(timing), flush=True)


# ----------------------------------------------------------------------------------------------
# Checks (files only).

def principled_direct(base, rough, n, l, v):
    """Approximate Principled v1 direct reflection f * cos(theta_l): Disney diffuse (with
    retro-reflection) + GGX/Smith specular with Schlick Fresnel, F0 = 0.04."""
    cl = np.clip((n * l).sum(1), 1e-6, 1)
    cv = np.clip((n * v).sum(1), 1e-6, 1)
    h = l + v
    h /= np.linalg.norm(h, axis=1, keepdims=True)
    ch = np.clip((n * h).sum(1), 0, 1)
    lh = np.clip((l * h).sum(1), 0, 1)
    fl, fv = (1 - cl) ** 5, (1 - cv) ** 5
    fd90 = 0.5 + 2 * rough * lh * lh
    diff = base / math.pi * ((1 + (fd90 - 1) * fl) * (1 + (fd90 - 1) * fv))[:, None]
    a2 = np.maximum(rough ** 2, 1e-4) ** 2
    d = a2 / (math.pi * (ch * ch * (a2 - 1) + 1) ** 2)

    def g1(c):
        return 2 * c / (c + np.sqrt(a2 + (1 - a2) * c * c))
    f = 0.04 + 0.96 * (1 - lh) ** 5
    spec = d * g1(cl) * g1(cv) * f / (4 * cl * cv)
    return (diff + spec[:, None]) * cl[:, None]


def check(cap_dir):
    t0 = time.time()
    cap = json.load(open(os.path.join(cap_dir, "capture.json")))
    v, vt, vn, fv, ft, fn = read_obj(os.path.join(cap_dir, cap["mesh"]))
    cams = {c["id"]: c for c in cap["cameras"]}
    lights = {l["id"]: l for l in cap["lights"]}
    res = {}

    # UV overlap check at 2048^2.
    n_uv = 2048
    uvp = np.stack([vt[:, 0] * n_uv - 0.5, (1 - vt[:, 1]) * n_uv - 0.5], 1)
    # rasterise per corner: each triangle's uv corners are ft rows
    pix, tri, _ = rasterize(uvp, ft, n_uv, n_uv)
    cnt = np.bincount(pix, minlength=n_uv * n_uv)
    res["uv"] = {"overlapping_texels_at_2048": int((cnt > 1).sum()),
                 "covered_fraction": float((cnt > 0).mean())}
    print("uv", res["uv"], flush=True)

    base8 = read_png(os.path.join(cap_dir, "gt_basecolor.png"))
    rough8 = read_png(os.path.join(cap_dir, "gt_roughness.png"))

    # Per (camera, angle): rasterise mesh.obj with K, cam_from_world, turntable; compare masks;
    # compare photographs with masks.
    views = sorted({(im["camera"], im["turntable_deg"]) for im in cap["images"]})
    mask_diff, mask_px, lit_out, lit_out1, lit_out2, lit_tot, unlit_mask = 0, 0, 0, 0, 0, 0, 0
    img_stats = {"n": 0, "missing": 0, "nonfinite": 0, "negative": 0, "max": 0.0, "object_frac": []}
    raster = {}
    worst_view = (0, None)
    proj_check = {"vertices": 0, "outside_mask": 0, "outside_mask_dilated1": 0}
    for cam_id, ang in views:
        c = cams[cam_id]
        w, h = c["width"], c["height"]
        Kc = np.array(c["K"])
        m = np.array(c["cam_from_world"])
        R = m[:3, :3] @ rot_z(ang)
        pc = v @ R.T + m[:3, 3]
        p2 = np.stack([Kc[0, 0] * pc[:, 0] / pc[:, 2] + Kc[0, 2],
                       Kc[1, 1] * pc[:, 1] / pc[:, 2] + Kc[1, 2]], 1)
        pix, tri, bary = rasterize(p2, fv, w, h, depth=pc[:, 2])
        mine = np.zeros(w * h, bool)
        mine[pix] = True
        mine = mine.reshape(h, w)
        mask = read_png(os.path.join(cap_dir, "masks", "%s_%03d.png" % (cam_id, int(ang)))) > 127
        d = int((mine != mask).sum())
        mask_diff += d
        mask_px += int(mask.sum())
        raster[(cam_id, ang)] = (pix, tri, bary, pc)
        # Visible vertices (in front, nearest at their pixel) projected: inside the mask?
        iu = np.round(p2[:, 0]).astype(int)
        iv = np.round(p2[:, 1]).astype(int)
        inb = (iu >= 0) & (iv >= 0) & (iu < w) & (iv < h)
        zbuf = np.full(w * h, np.inf)
        zz = (bary * pc[fv[tri], 2]).sum(1)
        zbuf[pix] = zz
        vis = inb.copy()
        vis[inb] = pc[inb, 2] <= zbuf[iv[inb] * w + iu[inb]] + 1e-3
        sel = np.nonzero(vis)[0][::50]
        proj_check["vertices"] += len(sel)
        proj_check["outside_mask"] += int((~mask[iv[sel], iu[sel]]).sum())
        proj_check["outside_mask_dilated1"] += int((~dilate(mask, 1)[iv[sel], iu[sel]]).sum())
        # Photographs of this view.
        lit = np.zeros((h, w), bool)
        for im in cap["images"]:
            if im["camera"] != cam_id or im["turntable_deg"] != ang:
                continue
            if not os.path.exists(os.path.join(cap_dir, im["file"])):
                img_stats["missing"] += 1
                continue
            a = read_exr(os.path.join(cap_dir, im["file"]))
            assert a.shape == (h, w, 3), (im["file"], a.shape)
            img_stats["n"] += 1
            img_stats["nonfinite"] += int((~np.isfinite(a)).sum())
            img_stats["negative"] += int((a < 0).sum())
            img_stats["max"] = max(img_stats["max"], float(np.nanmax(a)))
            pos = a.max(2) > 1e-4
            img_stats["object_frac"].append(float(pos.mean()))
            lit |= a.max(2) > 0
        lo_ = int((lit & ~mask).sum())
        lit_tot += int(lit.sum())
        lit_out += lo_
        lit_out1 += int((lit & ~dilate(mask, 1)).sum())
        lit_out2 += int((lit & ~dilate(mask, 2)).sum())
        unlit_mask += int((mask & ~lit).sum())
        if lo_ / max(1, lit.sum()) > worst_view[0]:
            worst_view = (lo_ / max(1, lit.sum()), "%s_%03d" % (cam_id, int(ang)))
    of = np.array(img_stats["object_frac"])
    res["images"] = {"count": img_stats["n"], "expected": len(cap["images"]),
                     "missing": img_stats["missing"],
                     "nonfinite_values": img_stats["nonfinite"],
                     "negative_values": img_stats["negative"], "max_value": img_stats["max"],
                     "object_fraction_mean": float(of.mean()), "object_fraction_min": float(of.min()),
                     "object_fraction_max": float(of.max())}
    res["masks_vs_numpy_raster"] = {"differing_pixels": mask_diff, "mask_pixels": mask_px}
    res["vertex_projection"] = proj_check
    res["photos_vs_masks"] = {
        "lit_pixels": lit_tot,
        "outside_mask_pct": 100.0 * lit_out / lit_tot,
        "outside_mask_dilated1_pct": 100.0 * lit_out1 / lit_tot,
        "outside_mask_dilated2_pct": 100.0 * lit_out2 / lit_tot,
        "worst_view_outside_pct": [100.0 * worst_view[0], worst_view[1]],
        "mask_pixels_unlit_by_all_lights_pct": 100.0 * unlit_mask / max(1, mask_px)}
    print("images", res["images"], flush=True)
    print("masks", res["masks_vs_numpy_raster"], res["vertex_projection"], flush=True)
    print("photos_vs_masks", res["photos_vs_masks"], flush=True)

    # Radiometry on train images: matte, lit, unshadowed, locally uniform pixels.
    bvh = BVHTree.FromPolygons([tuple(p) for p in v], [tuple(f) for f in fv.tolist()],
                               all_triangles=True)
    train = [i for i, im in enumerate(cap["images"]) if im["split"] == "train"
             and os.path.exists(os.path.join(cap_dir, im["file"]))]
    pick = train[:: max(1, len(train) // 12)][:12]
    ratios_l, ratios_p, per_img = [], [], []
    sh_stats = {"lit": 0, "lit_but_dark": 0, "shadowed": 0, "shadowed_but_bright": 0}
    for ii in pick:
        im = cap["images"][ii]
        c = cams[im["camera"]]
        w, h = c["width"], c["height"]
        m = np.array(c["cam_from_world"])
        Rt = rot_z(im["turntable_deg"])
        pix, tri, bary, pc = raster[(im["camera"], im["turntable_deg"])]
        zc = pc[fv[tri], 2]
        bp = bary / zc
        bp /= bp.sum(1, keepdims=True)                        # perspective-correct
        P = (bp[:, :, None] * v[fv[tri]]).sum(1)               # object frame
        nrm = (bp[:, :, None] * vn[fn[tri]]).sum(1)
        nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
        uvs = (bp[:, :, None] * vt[ft[tri]]).sum(1)
        base = srgb_to_linear(bilinear(base8, uvs) / 255.0)    # bilinear bytes, then decode
        rough = bilinear(rough8[..., None], uvs)[:, 0] / 255.0
        cam_c = Rt.T @ (-m[:3, :3].T @ m[:3, 3])              # camera centre, object frame
        lp = Rt.T @ np.array(lights[im["light"]]["position"])
        I = np.array(lights[im["light"]]["intensity"])
        tol = P - lp
        dist = np.linalg.norm(tol, axis=1)
        ldir = -tol / dist[:, None]
        vdir = cam_c - P
        vdir /= np.linalg.norm(vdir, axis=1, keepdims=True)
        cl = (nrm * ldir).sum(1)
        cv = (nrm * vdir).sum(1)
        facing = np.nonzero((cl > 0.3) & (cv > 0.3))[0]
        shadowed = np.zeros(len(pix), bool)
        for k in facing:
            o = Vector(P[k] + nrm[k] * 1e-4)
            hit = bvh.ray_cast(o, Vector(ldir[k]), float(dist[k]))
            shadowed[k] = hit[0] is not None
        isf = np.zeros(len(pix), bool)
        isf[facing] = True
        unsh = isf & ~shadowed & (rough > 0.55)
        # Shadow agreement: facing pixels >= 2 px from a predicted shadow boundary; the photo
        # over the direct Lambert prediction should be small in shadow and ~1 when lit.
        sh_img = np.zeros(h * w, np.int8) - 1
        sh_img[pix[facing]] = shadowed[facing]
        sh_img = sh_img.reshape(h, w)
        near = dilate(sh_img == 1, 2) & dilate(sh_img == 0, 2)
        photo_all = read_exr(os.path.join(cap_dir, im["file"])).reshape(-1, 3)
        lam_all = (base / math.pi * (I * np.clip(cl, 0, 1)[:, None])
                   / dist[:, None] ** 2).sum(1)
        rat = photo_all[pix].sum(1) / np.maximum(lam_all, 1e-9)
        far = isf & ~near.ravel()[pix]
        sh_stats["lit"] += int((far & ~shadowed).sum())
        sh_stats["lit_but_dark"] += int((far & ~shadowed & (rat < 0.5)).sum())
        sh_stats["shadowed"] += int((far & shadowed).sum())
        sh_stats["shadowed_but_bright"] += int((far & shadowed & (rat > 0.5)).sum())
        good = np.zeros(h * w, bool)
        good[pix[unsh]] = True
        good = good.reshape(h, w)
        # locally uniform: 3x3 neighbourhood all good and same albedo within 2 %
        alb = np.zeros((h * w, 3))
        alb[pix] = base
        alb = alb.reshape(h, w, 3)
        ok = good.copy()
        for dy in (-1, 0, 1):
            for dx in (-1, 0, 1):
                sh = np.roll(np.roll(good, dy, 0), dx, 1)
                sa = np.roll(np.roll(alb, dy, 0), dx, 1)
                ok &= sh & (np.abs(sa - alb).max(2) < 0.02 * alb.max(2) + 1e-6)
        photo = read_exr(os.path.join(cap_dir, im["file"])).reshape(-1, 3)
        where = np.zeros(h * w, np.int64) - 1
        where[pix] = np.arange(len(pix))
        sel = where[np.nonzero(ok.ravel())[0]]
        pix_sel = pix[sel]
        obs = photo[pix_sel].sum(1)
        lam = (base[sel] / math.pi * (I * cl[sel, None]) / dist[sel, None] ** 2).sum(1)
        pri = (principled_direct(base[sel], rough[sel], nrm[sel], ldir[sel], vdir[sel])
               * I / dist[sel, None] ** 2).sum(1)
        rl, rp = obs / lam, obs / pri
        ratios_l.append(rl)
        ratios_p.append(rp)
        per_img.append({"image": im["file"], "pixels": int(len(sel)),
                        "median_obs_over_lambert": float(np.median(rl)) if len(rl) else None})
    rl = np.concatenate(ratios_l)
    rp = np.concatenate(ratios_p)
    res["radiometry"] = {
        "pixels": int(len(rl)), "images": len(pick),
        "obs_over_lambert": {"median": float(np.median(rl)), "p10": float(np.percentile(rl, 10)),
                             "p90": float(np.percentile(rl, 90))},
        "obs_over_principled_direct": {"median": float(np.median(rp)),
                                       "p10": float(np.percentile(rp, 10)),
                                       "p90": float(np.percentile(rp, 90))},
        "per_image": per_img,
        "shadow_agreement": dict(sh_stats, definition=(
            "pixels facing the light and camera (cos > 0.3), >= 2 px from a predicted cast-shadow "
            "boundary (BVH ray to the light); dark/bright = photo / direct Lambert below/above "
            "0.5"))}
    print("radiometry", {k: res["radiometry"][k] for k in
                         ("pixels", "obs_over_lambert", "obs_over_principled_direct",
                          "shadow_agreement")}, flush=True)
    res["check_seconds"] = round(time.time() - t0, 1)
    with open(os.path.join(cap_dir, "checks", "validation.json"), "w") as fh:
        json.dump(res, fh, indent=1)
    print("CHECK DONE", flush=True)


def main():
    argv = sys.argv[sys.argv.index("--") + 1:] if "--" in sys.argv else []
    ap = argparse.ArgumentParser(prog="turntable_capture.py")
    ap.add_argument("--object", default="knot", choices=sorted(OBJECTS))
    ap.add_argument("--rig", choices=sorted(RIGS),
                    help="camera/light rig (default: the object's own: knot -> knot, "
                         "teapot -> suzanne)")
    ap.add_argument("--seed", type=int, default=2)
    ap.add_argument("--res", type=int, default=320)
    ap.add_argument("--spp", type=int, default=32)
    ap.add_argument("--out")
    ap.add_argument("--skip-render", action="store_true",
                    help="everything but the photographs (for testing the setup)")
    ap.add_argument("--uv-angle", type=float, default=35.0,
                    help="Smart UV Project angle limit, degrees")
    ap.add_argument("--limit", type=int, default=0,
                    help="render only the first N photographs (for testing; 0 = all)")
    ap.add_argument("--only-split", choices=["train", "holdout"],
                    help="render only that split's photographs (diagnostics)")
    ap.add_argument("--noise-seed-offset", type=int, default=0,
                    help="added to every Cycles seed: an independent noise realisation of the "
                         "same capture (diagnostics; 500 keeps clear of the default seeds)")
    ap.add_argument("--check", metavar="DIR", help="check an existing capture instead")
    args = ap.parse_args(argv)
    if args.check:
        check(args.check)
    else:
        if not args.out:
            ap.error("--out is required")
        capture(args)


main()

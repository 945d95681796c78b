#!/usr/bin/env python3
"""Render a photo-like test capture with true object masks: one of the ground-truth generator's
objects (../shared/tools/make_gt_dataset.py) placed on a table, on a wall or on a stand, with plain
or cluttered surroundings, rendered opaque (the background is in every photo, as in a real capture).

Output (what `svgir masks` / `svgir capture` read, plus the truth):

    OUT/transforms.json   nerfstudio/instant-ngp layout: fl_x fl_y cx cy w h, frames[] with
                          file_path "images/NNN.png" and the camera-to-world transform_matrix
                          (OpenGL convention: the camera looks down -Z, +Y up)
    OUT/images/NNN.png    8-bit sRGB photo of the whole scene
    OUT/masks_true/NNN.png the object's true mask (white = object), from a second render in which
                          everything but the object is a holdout: the object's own coverage, with
                          the surroundings occluding it where they are in front
    OUT/capture.json      layout, objects, render settings

Layouts:
    table    the object stands on a large floor; photos from all around, 10-60 deg above it
    wall     the object hangs on a wall (its back touches it); photos from the front half-space only
    stand    the object stands on a thin pole over a distant floor; photos from all around

Set up as for the generator (Python 3.11): pip install bpy==5.0.1 OpenEXR pillow numpy

    python tools/blender_capture.py --layout wall --clutter --scene bowl_fruit --out /tmp/wall
"""

import argparse
import json
import math
import os
import sys
import time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.join(HERE, "..", "..", "shared", "tools"))
import make_gt_dataset as g  # noqa: E402  (the generator: scenes, materials, render set-up)

import bpy  # noqa: E402
from mathutils import Matrix  # noqa: E402
from PIL import Image  # noqa: E402


def plane(name, size, center, rotation=(0.0, 0.0, 0.0)):
    s = size / 2
    ob = g.mesh_object(name, [(-s, -s, 0), (s, -s, 0), (s, s, 0), (-s, s, 0)], [(0, 1, 2, 3)], smooth=False)
    ob.rotation_euler = rotation
    ob.location = center
    return ob


def box(name, size, center, rz=0.0):
    sx, sy, sz = (v / 2 for v in size)
    verts = [(x, y, z) for z in (-sz, sz) for y in (-sy, sy) for x in (-sx, sx)]
    faces = [(0, 2, 3, 1), (4, 5, 7, 6), (0, 1, 5, 4), (2, 6, 7, 3), (0, 4, 6, 2), (1, 3, 7, 5)]
    ob = g.mesh_object(name, verts, faces, smooth=False)
    ob.location = center
    ob.rotation_euler = (0.0, 0.0, rz)
    return ob


def cylinder(name, radius, z0, z1, xy=(0.0, 0.0), segments=48):
    prof = [(0.0, z0), (radius, z0), (radius, z1), (0.0, z1)]
    ob = g.lathe(name, g.densify(np.asarray(prof), 0.05), segments)
    ob.location = (xy[0], xy[1], 0.0)
    return ob


def plain_mat(name, rgb, roughness=0.7):
    def build(nb):
        c = nb.new("ShaderNodeRGB")
        c.outputs[0].default_value = (*rgb, 1.0)
        r = nb.new("ShaderNodeValue")
        r.outputs[0].default_value = roughness
        return c.outputs[0], r.outputs[0]
    return g.make_material(name, build, {"pattern": "plain"})[0]


def bbox(objects):
    bpy.context.view_layer.update()
    v = np.concatenate([g.world_vertices(o) for o in objects])
    return v.min(0), v.max(0)


def surroundings(layout, clutter, objects, rng):
    """The non-object geometry of the layout; returns the list of its Blender objects."""
    lo, hi = bbox(objects)
    out = []
    if layout == "table":
        floor = plane("floor", 14.0, (0.0, 0.0, lo[2]))
        if clutter:
            g.assign(floor, g.mat_tiles("floor_tiles", [(0.55, 0.42, 0.30), (0.35, 0.25, 0.18), (0.62, 0.55, 0.45)],
                                        scale=2.0)[0])
        else:
            g.assign(floor, plain_mat("floor_plain", (0.80, 0.80, 0.78)))
        out.append(floor)
    elif layout == "wall":
        wall = plane("wall", 14.0, (0.0, hi[1], 0.0), rotation=(math.radians(90), 0.0, 0.0))
        if clutter:
            g.assign(wall, g.mat_stripes("wallpaper", (0.55, 0.60, 0.45), (0.85, 0.80, 0.65), direction="X",
                                         scale=3.0)[0])
        else:
            g.assign(wall, plain_mat("paint", (0.85, 0.83, 0.78)))
        out.append(wall)
    elif layout == "stand":
        floor_z = lo[2] - 1.6
        floor = plane("floor", 14.0, (0.0, 0.0, floor_z))
        g.assign(floor, g.mat_checker("floor_checker", (0.25, 0.25, 0.28), (0.70, 0.68, 0.62), scale=1.5)[0]
                 if clutter else plain_mat("floor_plain", (0.6, 0.6, 0.6)))
        pole = cylinder("pole", 0.04, floor_z, lo[2] + 0.02)
        base = cylinder("pole_base", 0.35, floor_z, floor_z + 0.05)
        metal = plain_mat("pole_metal", (0.15, 0.15, 0.15), roughness=0.35)
        g.assign(pole, metal)
        g.assign(base, metal)
        out += [floor, pole, base]
    if clutter:
        mats = [plain_mat(f"clutter_{i}", tuple(rng.uniform(0.1, 0.9, 3)), roughness=float(rng.uniform(0.2, 0.9)))
                for i in range(6)]
        if layout == "wall":
            # Picture frames and shelves on the wall, clear of the object.
            for i, (x, z) in enumerate([(-2.6, 1.2), (2.5, -0.9), (-2.2, -1.8), (2.8, 1.9), (0.2, 2.4)]):
                size = (float(rng.uniform(0.6, 1.2)), 0.08, float(rng.uniform(0.5, 1.0)))
                ob = box(f"frame_{i}", size, (x, hi[1] - 0.04, z))
                g.assign(ob, mats[i % len(mats)])
                out.append(ob)
        else:
            base_z = out[0].location[2]
            for i in range(6):
                ang = 2 * math.pi * i / 6 + float(rng.uniform(-0.3, 0.3))
                r = float(rng.uniform(2.3, 3.2))
                x, y = r * math.cos(ang), r * math.sin(ang)
                kind = i % 3
                if kind == 0:
                    h = float(rng.uniform(0.3, 0.9))
                    ob = box(f"box_{i}", (float(rng.uniform(0.3, 0.7)), float(rng.uniform(0.3, 0.7)), h),
                             (x, y, base_z + h / 2), rz=float(rng.uniform(0, math.pi)))
                elif kind == 1:
                    ob = cylinder(f"can_{i}", float(rng.uniform(0.12, 0.25)), base_z, base_z
                                  + float(rng.uniform(0.4, 1.0)), xy=(x, y))
                else:
                    rad = float(rng.uniform(0.15, 0.35))
                    ob = g.sphere(f"ball_{i}", rad, (x, y, base_z + rad))
                g.assign(ob, mats[i % len(mats)])
                out.append(ob)
    return out


def sample_points(objects, cams, focal, res, photos, n, rng):
    """SfM-like sparse points: `n` points drawn by area over the surfaces that face a camera and
    lie inside at least two photos (occlusion is ignored), coloured from the first such photo."""
    dg = bpy.context.evaluated_depsgraph_get()
    tris = []
    for ob in objects:
        me = ob.evaluated_get(dg).to_mesh()
        me.calc_loop_triangles()
        mw = np.array(ob.matrix_world)
        v = np.array([tuple(x.co) for x in me.vertices], dtype=np.float64)
        v = v @ mw[:3, :3].T + mw[:3, 3]
        t = np.array([tuple(x.vertices) for x in me.loop_triangles], dtype=np.int64)
        tris.append(v[t])
        ob.evaluated_get(dg).to_mesh_clear()
    tri = np.concatenate(tris)
    area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    out_p, out_c = [], []
    while len(out_p) < n:
        k = rng.choice(len(tri), size=4 * n, p=area / area.sum())
        a, b = rng.random((2, 4 * n))
        flip = a + b > 1
        a[flip], b[flip] = 1 - a[flip], 1 - b[flip]
        t = tri[k]
        p = t[:, 0] + a[:, None] * (t[:, 1] - t[:, 0]) + b[:, None] * (t[:, 2] - t[:, 0])
        nrm = np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0])
        seen = np.zeros(len(p), dtype=np.int64)
        colour = np.full((len(p), 3), -1.0)
        for m, photo in zip(cams, photos):
            rel = p - m[:3, 3]
            cam = rel @ m[:3, :3]  # camera frame: x right, y up, looking down -z
            z = -cam[:, 2]
            ok = (z > 0.05) & (np.einsum("ij,ij->i", nrm, -rel) > 0)
            u = res / 2 + focal * cam[:, 0] / np.maximum(z, 1e-9)
            v = res / 2 - focal * cam[:, 1] / np.maximum(z, 1e-9)
            ok &= (u >= 0) & (u < res) & (v >= 0) & (v < res)
            seen += ok
            first = ok & (colour[:, 0] < 0)
            colour[first] = photo[v[first].astype(int), u[first].astype(int), :3] / 255.0
        keep = seen >= 2
        out_p.extend(p[keep])
        out_c.extend(colour[keep])
    return np.array(out_p[:n]), np.array(out_c[:n])


def write_ply(path, pts, rgb):
    """Binary little-endian PLY: float x y z, uchar red green blue (what COLMAP's and
    nerfstudio's point files hold)."""
    head = ("ply\nformat binary_little_endian 1.0\nelement vertex %d\nproperty float x\nproperty float y\n"
            "property float z\nproperty uchar red\nproperty uchar green\nproperty uchar blue\nend_header\n"
            % len(pts))
    rec = np.zeros(len(pts), dtype=[("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("r", "u1"), ("g", "u1"), ("b", "u1")])
    rec["x"], rec["y"], rec["z"] = pts[:, 0], pts[:, 1], pts[:, 2]
    c = np.clip(np.round(rgb * 255), 0, 255).astype(np.uint8)
    rec["r"], rec["g"], rec["b"] = c[:, 0], c[:, 1], c[:, 2]
    with open(path, "wb") as f:
        f.write(head.encode())
        f.write(rec.tobytes())


def cameras(layout, n, seed):
    """Camera-to-world matrices (Blender convention), looking at the object's centre."""
    rng = np.random.default_rng(seed)
    out = []
    for i in range(n):
        if layout == "wall":
            # Front half-space (the wall is at +y): azimuth within 65 deg of -y, elevation -25..40.
            az = -math.pi / 2 + math.radians(65) * (2 * (i + rng.uniform(0.2, 0.8)) / n - 1)
            el = math.radians(rng.uniform(-25, 40))
        else:
            lo_el, hi_el = (10, 60) if layout == "table" else (-5, 55)
            az = 2 * math.pi * (i + rng.uniform(0.2, 0.8)) / n
            el = math.radians(lo_el + (hi_el - lo_el) * ((i * 0.618034) % 1.0))
        r = g.CAMERA_DISTANCE * float(rng.uniform(0.9, 1.1))
        eye = r * np.array([math.cos(el) * math.cos(az), math.cos(el) * math.sin(az), math.sin(el)])
        out.append(g.look_at(eye, target=(0.0, 0.0, float(rng.normal(0, 0.05)))))
    return out


def main():
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--scene", choices=sorted(g.SCENES), required=True)
    p.add_argument("--layout", choices=["table", "wall", "stand"], required=True)
    p.add_argument("--clutter", action="store_true", help="patterned surfaces and other objects around")
    p.add_argument("--out", required=True)
    p.add_argument("--res", type=int, default=200)
    p.add_argument("--views", type=int, default=36)
    p.add_argument("--spp", type=int, default=48)
    p.add_argument("--light", default="builtin:forest", help="environment map ([NAME=]PATH[@STRENGTH])")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--threads", type=int, default=2)
    p.add_argument("--jpeg", action="store_true", help="save the photos as JPEG (quality 92), as a camera would")
    p.add_argument("--resume", action="store_true", help="keep the views already rendered")
    p.add_argument("--points", type=int, default=20000,
                   help="SfM-like sparse points written to points3D.ply (0: none, as a capture without them)")
    args = p.parse_args()

    with g.silence_fd(1):
        bpy.ops.wm.read_factory_settings(use_empty=True)
    ns = argparse.Namespace(res=args.res, threads=args.threads, spp=args.spp, bounces=3, clamp_indirect=4.0,
                            denoise=True, keep_exr=False)
    render_info = g.setup_render(ns)
    sc = bpy.context.scene
    builder, desc = g.SCENES[args.scene]
    objects = [o for o, _ in builder()]
    g.normalise_scene(objects)
    if args.layout == "wall":
        # Hang it: the scene's up (+z) turns to face the cameras (-y).
        for o in objects:
            o.matrix_world = Matrix.Rotation(math.radians(90), 4, "X") @ o.matrix_world
    rng = np.random.default_rng(args.seed)
    rest = surroundings(args.layout, args.clutter, objects, rng)
    light = g.parse_light(args.light)
    world = g.World(0.0)
    world.set(light)

    cam_data = bpy.data.cameras.new("camera")
    cam_data.lens_unit = "FOV"
    cam_data.sensor_fit = "HORIZONTAL"
    cam_data.angle = math.radians(g.DEFAULT_FOV_DEG)
    cam_data.clip_start = 0.05
    cam_data.clip_end = 100.0
    cam = bpy.data.objects.new("camera", cam_data)
    sc.collection.objects.link(cam)
    sc.camera = cam

    os.makedirs(os.path.join(args.out, "images"), exist_ok=True)
    os.makedirs(os.path.join(args.out, "masks_true"), exist_ok=True)
    focal = 0.5 * args.res / math.tan(0.5 * cam_data.angle)
    frames, rendered, t0 = [], {}, time.time()
    cams = cameras(args.layout, args.views, args.seed)
    for i, m in enumerate(cams):
        name = f"{i:03d}.png"
        photo = f"{i:03d}.jpg" if args.jpeg else name
        cam.matrix_world = Matrix(m.tolist())
        bpy.context.view_layer.update()
        sc.cycles.seed = args.seed * 1000 + i
        frames.append({"file_path": f"images/{photo}", "transform_matrix": np.asarray(cam.matrix_world).tolist()})
        if args.resume and all(os.path.isfile(os.path.join(args.out, d, f)) for d, f in (("images", photo),
                                                                                     ("masks_true", name))):
            continue
        # The photo: everything, opaque.
        sc.render.film_transparent = False
        sc.cycles.samples = args.spp
        sc.cycles.use_denoising = True
        for o in rest:
            o.is_holdout = False
        g.render_to(os.path.join(args.out, "images", name))
        # The points take their colours from the render itself, not from the JPEG's compression.
        rendered[i] = np.asarray(Image.open(os.path.join(args.out, "images", name)).convert("RGB"))
        if args.jpeg:
            png = os.path.join(args.out, "images", name)
            Image.fromarray(rendered[i]).save(os.path.join(args.out, "images", photo), quality=92)
            os.remove(png)
        # The truth: the object's coverage, the rest held out (it still occludes).
        sc.render.film_transparent = True
        sc.cycles.samples = 16
        sc.cycles.use_denoising = False
        for o in rest:
            o.is_holdout = True
        tmp = os.path.join(args.out, "masks_true", "_alpha.png")
        g.render_to(tmp)
        alpha = np.asarray(Image.open(tmp))[..., 3]
        Image.fromarray(np.where(alpha >= 128, 255, 0).astype(np.uint8), "L").save(
            os.path.join(args.out, "masks_true", name))
        os.remove(tmp)
        g.log(f"[{args.layout}{'+clutter' if args.clutter else ''} {args.scene}] view {i + 1}/{args.views} "
              f"({time.time() - t0:.0f} s)")
    meta = {"camera_model": "PINHOLE", "fl_x": focal, "fl_y": focal, "cx": args.res / 2, "cy": args.res / 2,
            "w": args.res, "h": args.res, "frames": frames}
    if args.points > 0:
        def photo_of(i, f):  # a view kept from an earlier --resume run is read back from its file
            if i in rendered:
                return rendered[i]
            return np.asarray(Image.open(os.path.join(args.out, f["file_path"])).convert("RGB"))
        photos = [photo_of(i, f) for i, f in enumerate(frames)]
        pts, rgb = sample_points(objects + rest, cams, focal, args.res, photos, args.points, rng)
        write_ply(os.path.join(args.out, "points3D.ply"), pts, rgb)
        meta["ply_file_path"] = "points3D.ply"
    with open(os.path.join(args.out, "transforms.json"), "w") as f:
        json.dump(meta, f, indent=1)
    with open(os.path.join(args.out, "capture.json"), "w") as f:
        json.dump({"scene": args.scene, "description": desc, "layout": args.layout, "clutter": args.clutter,
                   "object": [o.name for o in objects], "surroundings": [o.name for o in rest],
                   "light": light, "views": args.views, "res": args.res, "seed": args.seed,
                   "render": render_info, "seconds": round(time.time() - t0, 1)}, f, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())

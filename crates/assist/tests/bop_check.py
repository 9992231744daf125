"""Checks the BOP side of a folder written by `assist generate`, reading it as the
bop_toolkit's readers do (inout.load_json with integer keys, load_scene_camera,
load_scene_gt, load_ply: binary PLY of float/uchar/int properties and triangles).

    python bop_check.py OUT

- every sample is a BOP scene: rgb/ and depth/ hold six-digit images (000000.png …), one
  per entry of scene_camera.json; mask/ and mask_visib/ hold IMAGE_GT.png for every
  ground-truth entry; scene_gt_info.json agrees with the masks and the depth image;
- models/models_info.json lists a model per annotated object id; each obj_XXXXXX.ply loads
  with triangles, in millimetres, its 3D box and diameter as listed;
- geometry by reprojection: the model's vertices, posed by cam_R_m2c/cam_t_m2c and
  projected by cam_K, fall on the object's silhouette (mask/), and the depth image at its
  visible pixels lies within the model's reach of cam_t_m2c.

Exits non-zero with a message on the first failure; prints a summary otherwise.
"""

import json
import struct
import sys
from pathlib import Path

import numpy as np
from PIL import Image


def fail(msg):
    print(f"FAIL: {msg}", file=sys.stderr)
    sys.exit(1)


def load_json_int_keys(path):
    def keys(x):
        return {int(k) if k.lstrip("-").isdigit() else k: v for k, v in x.items()}
    return json.loads(Path(path).read_text(), object_hook=keys)


def load_ply(path):
    """Vertices (n×3) and triangles (m×3) of a binary little-endian PLY, reading only the
    property types the bop_toolkit's reader knows."""
    formats = {"float": ("f", 4), "double": ("d", 8), "int": ("i", 4), "uchar": ("B", 1)}
    with open(path, "rb") as f:
        props, face_props, n_v, n_f, section = [], None, 0, 0, None
        while True:
            line = f.readline().decode("utf8").strip()
            if line.startswith("format") and "binary_little_endian" not in line:
                fail(f"{path}: {line}")
            if line.startswith("element vertex"):
                n_v, section = int(line.split()[-1]), "v"
            elif line.startswith("element face"):
                n_f, section = int(line.split()[-1]), "f"
            elif line.startswith("property list") and section == "f":
                _, _, count_t, index_t, name = line.split()
                if name not in ("vertex_indices", "vertex_index"):
                    fail(f"{path}: face property {name}")
                face_props = (count_t, index_t)
            elif line.startswith("property") and section == "v":
                _, t, name = line.split()
                if t not in formats:
                    fail(f"{path}: vertex property type {t} is not one the bop_toolkit reads")
                props.append((name, t))
            elif line == "end_header":
                break
        pts = np.zeros((n_v, 3))
        names = [p[0] for p in props]
        for i in range(n_v):
            vals = {}
            for name, t in props:
                fmt, size = formats[t]
                vals[name] = struct.unpack("<" + fmt, f.read(size))[0]
            pts[i] = [vals["x"], vals["y"], vals["z"]]
        faces = np.zeros((n_f, 3), np.int64)
        if face_props is None and n_f:
            fail(f"{path}: faces without vertex_indices")
        for i in range(n_f):
            fmt, size = formats[face_props[0]]
            n = struct.unpack("<" + fmt, f.read(size))[0]
            if n != 3:
                fail(f"{path}: a face with {n} corners (only triangles are read)")
            fmt, size = formats[face_props[1]]
            faces[i] = struct.unpack("<" + fmt * 3, f.read(size * 3))
        if not {"nx", "ny", "nz"} <= set(names):
            fail(f"{path}: no vertex normals")
    return pts, faces


def main():
    out = Path(sys.argv[1])
    info = load_json_int_keys(out / "models" / "models_info.json")
    models = {}
    for obj_id, mi in info.items():
        pts, faces = load_ply(out / "models" / f"obj_{obj_id:06d}.ply")
        if len(faces) < 4 or faces.max() >= len(pts):
            fail(f"obj_{obj_id:06d}.ply: {len(faces)} triangles, index {faces.max()} of {len(pts)} vertices")
        lo, size = pts.min(0), pts.max(0) - pts.min(0)
        if not np.allclose([mi["min_x"], mi["min_y"], mi["min_z"]], lo, atol=1e-3) or not np.allclose([mi["size_x"], mi["size_y"], mi["size_z"]], size, atol=1e-3):
            fail(f"models_info.json: object {obj_id}'s box differs from its model's")
        d = max(np.linalg.norm(pts - p, axis=1).max() for p in pts[:: max(1, len(pts) // 300)])
        if not (d - 1e-3 <= mi["diameter"] <= np.linalg.norm(size) + 1e-3):
            fail(f"models_info.json: object {obj_id}'s diameter {mi['diameter']} is outside [{d}, {np.linalg.norm(size)}]")
        if not (5.0 < mi["diameter"] < 5000.0):
            fail(f"object {obj_id}: a diameter of {mi['diameter']} is not in millimetres of a tabletop object")
        models[obj_id] = pts

    scenes = sorted((out / "samples").iterdir())
    n_images = n_gt = 0
    worst_off = 0.0
    for sdir in scenes:
        cams = load_json_int_keys(sdir / "scene_camera.json")
        gts = load_json_int_keys(sdir / "scene_gt.json")
        ginfo = load_json_int_keys(sdir / "scene_gt_info.json")
        for im_id, cam in cams.items():
            n_images += 1
            K = np.array(cam["cam_K"], float).reshape(3, 3)
            rgb = np.array(Image.open(sdir / "rgb" / f"{im_id:06d}.png"))
            depth = np.array(Image.open(sdir / "depth" / f"{im_id:06d}.png")).astype(np.float32) * cam["depth_scale"]
            h, w = rgb.shape[:2]
            if depth.shape != (h, w) or (cam["width"], cam["height"]) != (w, h):
                fail(f"{sdir.name} image {im_id}: rgb {rgb.shape}, depth {depth.shape}, camera {cam['width']}×{cam['height']}")
            if len(gts[im_id]) != len(ginfo[im_id]):
                fail(f"{sdir.name} image {im_id}: scene_gt and scene_gt_info differ in length")
            for gt_id, (gt, gi) in enumerate(zip(gts[im_id], ginfo[im_id])):
                n_gt += 1
                mask = np.array(Image.open(sdir / "mask" / f"{im_id:06d}_{gt_id:06d}.png")) > 127
                visib = np.array(Image.open(sdir / "mask_visib" / f"{im_id:06d}_{gt_id:06d}.png")) > 127
                if gi["px_count_all"] != int(mask.sum()) or gi["px_count_visib"] != int(visib.sum()):
                    fail(f"{sdir.name} {im_id}/{gt_id}: pixel counts differ from the masks")
                if (visib & ~mask).any():
                    fail(f"{sdir.name} {im_id}/{gt_id}: visible pixels outside the silhouette")
                if gi["px_count_valid"] != int((mask & (depth > 0)).sum()):
                    fail(f"{sdir.name} {im_id}/{gt_id}: px_count_valid differs")
                if gi["px_count_all"] and abs(gi["visib_fract"] - gi["px_count_visib"] / gi["px_count_all"]) > 1e-9:
                    fail(f"{sdir.name} {im_id}/{gt_id}: visib_fract")
                if gt["obj_id"] not in models or gi["px_count_all"] < 30:
                    continue
                R = np.array(gt["cam_R_m2c"], float).reshape(3, 3)
                t = np.array(gt["cam_t_m2c"], float).reshape(3, 1)
                pc = R @ models[gt["obj_id"]].T * gt.get("scale", [1, 1, 1])[0] + t
                uv = (K @ pc)[:2] / pc[2]
                inside = (uv[0] >= 0) & (uv[0] < w) & (uv[1] >= 0) & (uv[1] < h) & (pc[2] > 0)
                if inside.sum() < 10:
                    continue
                u, v = uv[0, inside].astype(int), uv[1, inside].astype(int)
                # Within two pixels of the silhouette.
                grown = mask.copy()
                for _ in range(2):
                    g = grown.copy()
                    g[1:] |= grown[:-1]; g[:-1] |= grown[1:]; g[:, 1:] |= grown[:, :-1]; g[:, :-1] |= grown[:, 1:]
                    grown = g
                on = grown[v, u].mean()
                worst_off = max(worst_off, 1.0 - on)
                if on < 0.9:
                    fail(f"{sdir.name} {im_id}/{gt_id} (object {gt['obj_id']}): only {on:.0%} of the posed model's vertices project onto its silhouette")
                if visib.any():
                    dz = depth[visib]
                    reach = info[gt["obj_id"]]["diameter"]
                    if np.median(np.abs(dz - t[2, 0])) > reach:
                        fail(f"{sdir.name} {im_id}/{gt_id}: depth {np.median(dz):.0f} mm is beyond the model's reach of cam_t_m2c z {t[2, 0]:.0f} mm")
    print(json.dumps({"scenes": len(scenes), "images": n_images, "ground_truths": n_gt, "models": len(models), "worst_off_silhouette": round(worst_off, 3)}))


if __name__ == "__main__":
    main()

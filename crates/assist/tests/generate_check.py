"""Checks a folder written by `assist generate` as its users' tools read it.

    python generate_check.py OUT TABLE_TOP_Z [TOLERANCE_M]

- pycocotools loads annotations/instances.json, and every annotation's decoded mask equals
  the pixels of that instance in the sample's instance PNG (views/panoptic/NAME.png), with
  holes filled when the masks are polygons (`info.masks`, and every segmentation is of that
  kind); every instance with visible pixels has an annotation;
- the COCO panoptic PNGs decode to the same segments as the instance PNGs;
- every placed (moved or added) object's lowest occupied point is within TOLERANCE_M
  (default 0.01 m) of the table top TABLE_TOP_Z, the ground truth of the capture (not the
  generator's own estimate), and its recorded support agrees;
- no two objects' occupied boxes (oriented, from the written poses) overlap.

Exits non-zero with a message on the first failure; prints a summary otherwise.
"""

import json
import sys
from pathlib import Path

import numpy as np
from PIL import Image
from pycocotools import mask as mask_utils
from pycocotools.coco import COCO


def fail(msg):
    print(f"FAIL: {msg}", file=sys.stderr)
    sys.exit(1)


def holes_filled(m):
    """`m` with every background pixel that the border's background does not reach
    (8-connected) set: what a polygon of the outer outlines covers."""
    h, w = m.shape
    outside = np.zeros_like(m, dtype=bool)
    stack = [(y, x) for y in range(h) for x in range(w) if not m[y, x] and (x in (0, w - 1) or y in (0, h - 1))]
    while stack:
        y, x = stack.pop()
        if outside[y, x] or m[y, x]:
            continue
        outside[y, x] = True
        for dy in (-1, 0, 1):
            for dx in (-1, 0, 1):
                if 0 <= y + dy < h and 0 <= x + dx < w:
                    stack.append((y + dy, x + dx))
    return (~outside).astype(np.uint8)


def obb_overlap(a, b, eps=1e-6):
    """Separating-axis test of two oriented boxes {center, half_size, rotation (rows)}."""
    ca, cb = np.array(a["center"]), np.array(b["center"])
    ha, hb = np.array(a["half_size"]), np.array(b["half_size"])
    ra, rb = np.array(a["rotation"]), np.array(b["rotation"])
    axes_a = [ra[:, k] for k in range(3)]
    axes_b = [rb[:, k] for k in range(3)]
    axes = axes_a + axes_b
    for x in axes_a:
        for y in axes_b:
            c = np.cross(x, y)
            n = np.linalg.norm(c)
            if n > 1e-9:
                axes.append(c / n)
    t = cb - ca
    for ax in axes:
        pa = sum(ha[k] * abs(axes_a[k] @ ax) for k in range(3))
        pb = sum(hb[k] * abs(axes_b[k] @ ax) for k in range(3))
        if abs(t @ ax) > pa + pb + eps:
            return False
    return True


def main():
    out = Path(sys.argv[1])
    table = float(sys.argv[2])
    tol = float(sys.argv[3]) if len(sys.argv) > 3 else 0.01
    coco = COCO(str(out / "annotations" / "instances.json"))
    masks = coco.dataset["info"]["masks"]
    if masks not in ("polygon", "rle"):
        fail(f"info.masks is {masks!r}")
    images = coco.loadImgs(coco.getImgIds())
    if not images:
        fail("no images in instances.json")
    n_masks = 0
    for img in images:
        name = img["view"]
        sample = out / "samples" / f"{img['sample']:06d}"
        ids = np.array(Image.open(sample / "views" / "panoptic" / f"{name}.png"))
        if ids.shape != (img["height"], img["width"]):
            fail(f"{img['file_name']}: instance PNG is {ids.shape}")
        anns = coco.loadAnns(coco.getAnnIds(imgIds=[img["id"]]))
        seen = set()
        for ann in anns:
            m = coco.annToMask(ann)
            want = (ids == ann["instance_id"]).astype(np.uint8)
            poly = isinstance(ann["segmentation"], list)
            if poly != (masks == "polygon"):
                fail(f"annotation {ann['id']}: a {'polygon' if poly else 'RLE'} segmentation in a file of {masks} masks")
            if poly and not np.array_equal(m, holes_filled(want)):
                fail(f"{img['file_name']}: annotation {ann['id']} (instance {ann['instance_id']}): its polygons cover other pixels than the instance PNG's outlines, in {int((m != holes_filled(want)).sum())} pixels")
            if not poly and not np.array_equal(m, want):
                fail(f"{img['file_name']}: annotation {ann['id']} (instance {ann['instance_id']}) differs from the instance PNG in {int((m != want).sum())} pixels")
            if ann["area"] != int(want.sum()):
                fail(f"annotation {ann['id']}: area {ann['area']} != {int(want.sum())}")
            x, y, w, h = ann["bbox"]
            ys, xs = np.nonzero(want)
            if [x, y, w, h] != [int(xs.min()), int(ys.min()), int(xs.max() - xs.min() + 1), int(ys.max() - ys.min() + 1)]:
                fail(f"annotation {ann['id']}: bbox {ann['bbox']} is not the mask's")
            # The compressed string decodes as pycocotools encodes it.
            enc = mask_utils.encode(np.asfortranarray(want))
            if not poly and enc["counts"].decode() != ann["segmentation"]["counts"]:
                fail(f"annotation {ann['id']}: RLE string differs from pycocotools' encoding")
            seen.add(ann["instance_id"])
            n_masks += 1
        present = set(int(v) for v in np.unique(ids)) - {0}
        if present != seen:
            fail(f"{img['file_name']}: instances {sorted(present)} in the PNG, annotations for {sorted(seen)}")
        pan = np.array(Image.open(sample / "views" / "panoptic_coco" / f"{name}.png")).astype(np.int64)
        seg = pan[..., 0] + 256 * pan[..., 1] + 65536 * pan[..., 2]
        expect = np.where(ids == 0, 1 << 16, ids.astype(np.int64))
        if not np.array_equal(seg, expect):
            fail(f"{img['file_name']}: COCO panoptic PNG differs from the instance PNG")
    pan_json = json.loads((out / "annotations" / "panoptic.json").read_text())
    if len(pan_json["annotations"]) != len(images):
        fail("panoptic.json: one annotation per image expected")

    placed = 0
    worst = 0.0
    pairs = 0
    for sdir in sorted((out / "samples").iterdir()):
        s = json.loads((sdir / "sample.json").read_text())
        objs = [o for o in s["objects"] if "occupied_box" in o]
        for o in objs:
            if o["status"] in ("moved", "added"):
                placed += 1
                err = abs(o["bottom"] - table)
                worst = max(worst, err)
                if err > tol:
                    fail(f"{sdir.name}: object {o['id']} {o['label']!r} rests at {o['bottom']:.4f}, the table top is {table} (off by {err * 1000:.1f} mm)")
                if abs(o["support"] - o["bottom"]) > 1e-6:
                    fail(f"{sdir.name}: object {o['id']}: bottom {o['bottom']} is not on its support {o['support']}")
        for i in range(len(objs)):
            for j in range(i + 1, len(objs)):
                pairs += 1
                a, b = objs[i], objs[j]
                if obb_overlap(a["occupied_box"], b["occupied_box"]):
                    fail(f"{sdir.name}: objects {a['id']} and {b['id']} overlap")
    if placed == 0:
        fail("no object was placed")
    print(json.dumps({
        "masks": masks,
        "images": len(images),
        "annotations": n_masks,
        "placed": placed,
        "worst_bottom_error_mm": round(worst * 1000, 2),
        "pairs_checked": pairs,
    }))


if __name__ == "__main__":
    main()

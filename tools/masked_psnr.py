#!/usr/bin/env python3
"""PSNR of a stage-1 run's test renders inside and outside foreground masks.

Splits the held-out error of a capture into the object (mask > 0.5) and the rest of the scene, with the masks
`svgir masks` writes (at the photos' size; area-resized here to the renders' size).

    python3 tools/masked_psnr.py RUN/test MASKS_DIR     # needs numpy and pillow
"""
import sys
from pathlib import Path

import numpy as np
from PIL import Image


def psnr(a, b, m):
    m = np.repeat(m[..., None], 3, axis=2)
    return -10 * np.log10((((a - b) ** 2) * m).sum() / max(m.sum(), 1))


def main(test_dir, masks_dir):
    rows = []
    for gt_path in sorted(Path(test_dir).glob("*_gt_rgb.png")):
        name = gt_path.name[: -len("_gt_rgb.png")]
        gt = np.asarray(Image.open(gt_path).convert("RGB"), dtype=np.float64) / 255
        pred = np.asarray(Image.open(gt_path.with_name(f"{name}_rgb.png")).convert("RGB"), dtype=np.float64) / 255
        h, w = gt.shape[:2]
        mask = Image.open(Path(masks_dir) / f"{name}.png").convert("L").resize((w, h), Image.BOX)
        fg = (np.asarray(mask, dtype=np.float64) / 255 > 0.5).astype(np.float64)
        rows.append((name, fg.mean(), psnr(pred, gt, fg), psnr(pred, gt, 1 - fg), psnr(pred, gt, np.ones_like(fg))))
    print("| view | object share | object PSNR | background PSNR | all |")
    print("|---|---|---|---|---|")
    for r in rows:
        print(f"| {r[0]} | {r[1]:.2f} | {r[2]:.2f} | {r[3]:.2f} | {r[4]:.2f} |")


if __name__ == "__main__":
    if len(sys.argv) != 3:
        sys.exit(__doc__)
    main(sys.argv[1], sys.argv[2])

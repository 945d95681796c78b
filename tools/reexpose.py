#!/usr/bin/env python3
"""Re-expose a TensoIR-layout scene's training photos, for testing per-photo colour corrections.

Each training photo `train_*/rgba.png` gets its own gain (0.6-1.3) and colour cast (up to 8% per
channel), clipped at white as a camera would; alpha and the test views are left as they are.

    python3 tools/reexpose.py SCENE OUT [--seed 7]     # needs numpy and Pillow

docs/capture.md measures `svgir train` and `svgir inverse` on the result with and without
`--exposure`.
"""
import argparse
import glob
import os
import shutil

import numpy as np
from PIL import Image

ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
ap.add_argument("scene")
ap.add_argument("out")
ap.add_argument("--seed", type=int, default=7)
a = ap.parse_args()
if os.path.exists(a.out):
    raise SystemExit(f"{a.out}: exists; remove it or name another folder")
photos = sorted(glob.glob(os.path.join(a.scene, "train_*", "rgba.png")))
if not photos:
    raise SystemExit(f"{a.scene}: no train_*/rgba.png (a TensoIR-layout scene is expected)")
shutil.copytree(a.scene, a.out)
rng = np.random.default_rng(a.seed)
for f in sorted(glob.glob(os.path.join(a.out, "train_*", "rgba.png"))):
    im = np.asarray(Image.open(f)).astype(np.float64) / 255
    gain = rng.uniform(0.6, 1.3)
    cast = 1 + rng.uniform(-0.08, 0.08, 3)
    rgb = np.clip(im[..., :3] * gain * cast, 0, 1)
    out = np.concatenate([rgb, im[..., 3:]], -1)
    Image.fromarray((out * 255 + 0.5).astype(np.uint8)).save(f)
print(f"re-exposed {len(photos)} training photos into {a.out}")

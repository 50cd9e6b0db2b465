"""Writes a bundled scene's flat core arrays to benches/data/<scene>.json for `cargo bench`
(the Rust bench needs no Python). Run: python benches/export_scene.py panda_blocks"""

import json
import sys
from pathlib import Path

import numpy as np

import profrobot.scenes

for name in sys.argv[1:] or ["panda_blocks"]:
    arrays = profrobot.scenes.load(name).core_arrays()
    doc = {k: (v.tolist() if isinstance(v, np.ndarray) else v) for k, v in arrays.items()}
    out = Path(__file__).parent / "data" / f"{name}.json"
    out.write_text(json.dumps(doc, separators=(",", ":")))
    print(f"wrote {out} ({out.stat().st_size / 1024:.0f} KiB)")

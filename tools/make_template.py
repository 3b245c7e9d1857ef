"""Rebuild the packaged ICT-FaceKit template (``src/faceretarget/data/templates/ict-face.npz``).

Reads the shared ICT-FaceKit folder (``../shared/data/ict-face``: neutral + 57 shapes, centimetres, MIT
licence) and writes a compact file: the neutral in metres (float32), its triangles, the 68 landmark vertices,
and for each shape only the vertices it moves (gaps between their indices, uint16, + float16 deltas in metres; the float16 rounding error
is printed: it must stay far below a tenth of a millimetre).

Usage::

    python tools/make_template.py [--ict ../shared/data/ict-face] [--out src/faceretarget/data/templates]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--ict", default=str(REPO.parent / "shared" / "data" / "ict-face"))
    ap.add_argument("--out", default=str(REPO / "src" / "faceretarget" / "data" / "templates"))
    a = ap.parse_args(argv)
    sys.path.insert(0, str(REPO / "src"))
    from faceretarget.io import read_rig

    rig = read_rig(a.ict)
    k = rig.mm_per_unit / 1000.0                                   # file units -> metres
    V = (rig.neutral.vertices * k).astype(np.float32)
    T = rig.neutral.triangles()
    assert len(V) < 65536
    T = T.astype(np.uint16)                                        # small: the wheel carries it
    D = np.asarray(rig.deltas, np.float64) * k
    out = {"neutral": V, "triangles": T, "landmarks": np.asarray(rig.landmarks, np.int32),
           "names": np.array(list(rig.source_names or rig.names))}
    worst = 0.0
    for i in range(len(out["names"])):
        mv = np.flatnonzero(np.abs(D[i]).max(axis=1) > 1e-7)
        d16 = D[i, mv].astype(np.float16)
        worst = max(worst, float(np.abs(d16.astype(np.float64) - D[i, mv]).max(initial=0.0)))
        out[f"gap_{i}"] = np.diff(mv, prepend=0).astype(np.uint16)   # moving vertices as gaps: compress well
        out[f"delta_{i}"] = d16
    dst = Path(a.out) / "ict-face.npz"
    dst.parent.mkdir(parents=True, exist_ok=True)
    np.savez_compressed(dst, **out)
    print(f"wrote {dst} ({dst.stat().st_size / 1e6:.2f} MB): {len(V)} vertices, {len(T)} triangles, "
          f"{len(out['names'])} shapes; float16 error at most {worst * 1e6:.1f} micrometres")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

"""Two runs of benchmarks/external_meshes.py (``--json``) on the same store: the difference of their median
final rotation errors (non-toppling pushes), with a 95 % interval from resampling whole meshes (a mesh's
pushes are not independent), and the share of pushes the second run does better on.

    python benchmarks/studies/paired_median.py A.json B.json
"""
import json
import sys

import numpy as np


def errors(path):
    return [r for r in json.load(open(path))["pushes"] if not r["toppled"]]


a, b = errors(sys.argv[1]), errors(sys.argv[2])
assert [r["mesh"] for r in a] == [r["mesh"] for r in b], "not the same pushes"
x, y = np.array([r["model_deg"] for r in a]), np.array([r["model_deg"] for r in b])
meshes = np.array([r["mesh"] for r in a])
groups = [np.flatnonzero(meshes == m) for m in np.unique(meshes)]
rng = np.random.default_rng(0)
diffs = []
for _ in range(2000):
    idx = np.concatenate([groups[i] for i in rng.integers(0, len(groups), len(groups))])
    diffs.append(np.median(y[idx]) - np.median(x[idx]))
print(f"median rotation error {np.median(x):.1f} -> {np.median(y):.1f} deg ({np.median(y) - np.median(x):+.1f}; 95 % interval "
      f"over meshes {np.percentile(diffs, 2.5):+.1f} to {np.percentile(diffs, 97.5):+.1f}); better on {np.mean(y < x):.0%} of the pushes")

"""A rocking-block model of the tilt just after a push, against the contact prior's "tilt taken away within
the step". The body pivots about the footprint's edge on the side the tilt spin lowers (Housner's rocking
block: I_p theta'' = -m g (b cos theta - h sin theta), b the edge's horizontal distance from the centre of
mass, h its height, I_p about the edge from the store's inertia tensor), with sliding friction's torque
while the push slides; a return to theta = 0 ends the rocking (plastic impact) or hands it to the opposite
edge (housner). Scored over the first 0.5 s of the non-toppling test pushes: the summed error of the
vertical velocity and tilt-spin changes, as a share of the sequences' summed velocity / spin changes
(Table 1's denominators); and the model's own topple call against the label.

    python benchmarks/studies/rocking_block.py runs/t1/speakers_30hz.zarr [plastic|housner]
"""
import sys, numpy as np
from physdyn.data.store import load_store
from physdyn.data.windows import world_oriented_points
from physdyn.geometry.rotations import quat_to_matrix
s = load_store(sys.argv[1]); impact = sys.argv[2] if len(sys.argv) > 2 else "plastic"
rate = float(s.rate_hz); mu = float(np.median(s.friction)); g = 9.81; H = 1 / 960
test = [i for i in range(s.num_sims) if s.split[i] == 2]
def rock(P, Iw, m, v0, w0, steps):
    wt = np.array([w0[0], w0[1], 0.0]); om = np.linalg.norm(wt)
    out_w = np.zeros((steps + 1, 3)); out_vz = np.zeros(steps + 1); toppled = False
    out_w[0] = wt; out_vz[0] = v0[2]
    if om < 1e-6: return out_w, out_vz, False
    a = wt / om; d = np.array([-a[1], a[0], 0.0])
    z = P[:, 2]; zmin = z.min(); foot = P[z < zmin + 0.005]
    b = -np.min(foot @ d); h = -zmin
    if b <= 0: b = 1e-3
    Ia = a @ Iw @ a; Ip = Ia + m * (b * b + h * h)
    u = v0[:2]; speed = np.linalg.norm(u); uhat = np.r_[u / max(speed, 1e-9), 0.0]; ud = uhat @ d
    t_slide = speed / (mu * g)
    th, Om, t = 0.0, om, 0.0; n_sub = int(round(1 / (rate * H))); alive = True; bb = b
    for k in range(1, steps + 1):
        for _ in range(n_sub):
            if not alive: break
            Hc = bb * np.sin(th) + h * np.cos(th)
            acc = -(m * g / Ip) * (bb * np.cos(th) - h * np.sin(th))
            if t < t_slide: acc += -(m * mu * g * ud * Hc) / Ip
            Om += acc * H; th += Om * H; t += H
            if th > np.arctan2(bb, h): toppled = True; alive = False
            if th < 0:
                if impact == "plastic": alive = False; Om = 0.0; th = 0.0
                else:  # Housner: the other edge becomes the pivot, angular momentum kept about it
                    b2 = max(np.max(foot @ d), 1e-3); R2 = b2 * b2 + h * h; Ip2 = Ia + m * R2
                    Om = Om * (Ia + m * (h * h - bb * b2)) / Ip2; th = 0.0
                    d, bb, Ip, ud, a = -d, b2, Ip2, -ud, -a
                    Om = -Om  # now lifting about the new edge (positive theta)
                    if abs(Om) < 0.2: alive = False; Om = 0.0
        out_w[k] = Om * a if alive or toppled else 0.0
        out_vz[k] = Om * (bb * np.cos(th) - h * np.sin(th)) if alive else 0.0
    return out_w, out_vz, toppled
E = {"kill_vz": 0, "rock_vz": 0, "kill_wxy": 0, "rock_wxy": 0, "den_v": 0, "den_w": 0}
top_pred, top_true = [], []
n = int(0.5 * rate)
for i in test:
    f = s.frames(i); sh = s.shape_id[i]; q0 = s.orientation_xyzw[f.start]
    P = world_oriented_points(s.points[sh], q0); R0 = quat_to_matrix(q0); A = quat_to_matrix(s.inertia_orientation_xyzw[sh])
    Iw = R0 @ A @ np.diag(s.inertia_diag[sh]) @ A.T @ R0.T
    v, w = s.linear_velocity[f], s.angular_velocity[f]
    steps = min(n, len(v) - 1)
    pw, pvz, top = rock(P, Iw, float(s.mass[sh]), v[0], w[0], steps)
    top_pred.append(top); top_true.append(bool(s.toppled[i]))
    if s.toppled[i]: continue
    dvz, dw = np.diff(v[: steps + 1, 2]), np.diff(w[: steps + 1, :2], axis=0)
    E["kill_vz"] += np.abs(-v[0, 2] - dvz[0]).sum() + np.abs(dvz[1:]).sum()
    E["kill_wxy"] += np.linalg.norm(-w[0, :2] - dw[0]) + np.linalg.norm(dw[1:], axis=1).sum()
    E["rock_vz"] += np.abs(np.diff(pvz) - dvz).sum(); E["rock_wxy"] += np.linalg.norm(np.diff(pw[:, :2], axis=0) - dw, axis=1).sum()
    E["den_v"] += np.linalg.norm(np.diff(v, axis=0), axis=1).sum(); E["den_w"] += np.linalg.norm(np.diff(w, axis=0), axis=1).sum()
print(f"{sys.argv[1]} ({impact}): first 0.5 s, as a share of the whole sequences' sum|dv| / sum|dw|:")
print(f"  v_z error: tilt taken away {E['kill_vz']/E['den_v']:.3f}, rocking model {E['rock_vz']/E['den_v']:.3f}")
print(f"  w_xy error: tilt taken away {E['kill_wxy']/E['den_w']:.3f}, rocking model {E['rock_wxy']/E['den_w']:.3f}")
tp, tt = np.array(top_pred), np.array(top_true)
print(f"  topple from the rocking model: accuracy {np.mean(tp == tt):.3f} (majority {max(tt.mean(), 1 - tt.mean()):.3f}), caught {np.sum(tp & tt)}/{tt.sum()}, false alarms {np.sum(tp & ~tt)}")

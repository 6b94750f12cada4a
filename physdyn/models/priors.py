"""Analytic priors a model can correct instead of predicting each change from scratch (``model.prior``).

The network then outputs the residual between the true change and the prior's, in normalised units. The
priors are pure functions of the velocities fed at step t, so teacher forcing and roll-outs use them alike.

- ``kinematic``: constant velocities over the step: dv = 0, dw = 0, dp = v dt, dtheta = w dt. It ties the
  position and rotation changes to the velocities the model itself carries.
- ``coulomb``: as kinematic, but the horizontal velocity decelerates at mu g (Coulomb sliding of a point
  mass, the baseline of ``physdyn.eval.baselines``) and stops when it reaches zero within the step:
  with u = |v_xy| and tau = min(dt, u / (mu g)), dv_xy = -mu g tau u_hat, dp_xy = (u tau - mu g tau^2 / 2) u_hat.
- ``planar``: as coulomb for the horizontal velocity, and the spin about the vertical slows linearly to stop
  when the slide stops (under Coulomb friction a body sliding and spinning on a plane stops translating and
  rotating at the same moment: Goyal, Ruina & Papadopoulos, "Planar sliding with dry friction", 1991), while
  spin about horizontal axes (tilt, which the ground's contact damps at once unless the object topples) and
  vertical velocity are taken away within the step. With t_stop = u / (mu g): dw_z = -w_z tau / t_stop,
  dtheta_z = w_z tau - w_z tau^2 / (2 t_stop), dw_xy = -w_xy, dtheta_xy = 0, dv_z = -v_z, dp_z = 0.
- ``contact``: as planar, but the slide and the spin are integrated together (sub-steps of 1/240 s) under
  Coulomb friction spread over the object's own footprint, read from its point cloud: among the points
  within 5 mm of the lowest, 4 spread as far apart as farthest-point sampling finds (the simulator's
  contact manifold keeps up to 4 points spanning the largest area; with 4 rather than 32 points the prior
  alone is closer on both position and rotation; ``model.contact_footprint=area`` takes instead the 4
  spanning the largest area, as the manifold does, which finds a box face's corners) carry the weight; the
  pressure over them is tilted so that its centre lies under the centre of mass (moment balance), leaning
  towards the travel as friction tips the object forward (half of mu times the height of the centre of
  mass, a fitted factor); the spin's
  inertia is the body's own I_zz / m where the caller knows it (``model.contact_inertia=body``), else 0.8
  times the points' mean squared distance from the vertical through the centre of mass (fitted). Each
  point's friction opposes its own sliding velocity v + w_z x r, so a spinning object slides farther and
  curves. Alone, with no learning, it predicts the final position of non-toppling quickstart objects at
  0.49-0.50x Coulomb sliding's median error and their rotation to 13-14 degrees with the body's inertia
  (0.50-0.54x, 14-15 degrees with the estimate; ``python benchmarks/priors.py``; docs/research/contact-prior.md). It
  needs the shape (``contact_geometry``) and the orientation since the points were taken.
"""

from __future__ import annotations

import math

import numpy as np
import torch

from physdyn.models.rotations import rotate

PRIORS = ("none", "kinematic", "coulomb", "planar", "contact")
SHAPE_PRIORS = ("contact",)  # priors that read the point cloud and the orientation since it was taken
RESIDUAL_CHANNELS = ("all", "linear", "angular")  # what the network's residual corrects (model.residual_channels)
# ... as a mask over the changes [dv (3), dw (3), dp (3), dtheta (3)]; "linear" is also what a model combined
# from two networks (DynamicsNetwork.linear_channels) takes from its second one
RESIDUAL_MASKS = {"all": [1.0] * 12, "linear": [1.0] * 3 + [0.0] * 3 + [1.0] * 3 + [0.0] * 3,
                  "angular": [0.0] * 3 + [1.0] * 3 + [0.0] * 3 + [1.0] * 3}
CONTACT_INERTIA = ("points", "body")  # where the contact prior's spin inertia comes from (model.contact_inertia)
FOOTPRINTS = ("spread", "area")  # how the contact prior picks its footprint points (model.contact_footprint)

# The contact prior's constants (see the module docstring; fitted on the quickstart store's training split).
SUPPORT_POINTS = 4        # footprint points: Bullet's contact manifold keeps up to 4, spanning the largest area
SUPPORT_DEPTH = 0.005     # m: points this close to the lowest one carry the weight
PRESSURE_LEAN = 0.5       # the centre of pressure leans by this times mu * (height of the centre of mass)
SPIN_INERTIA = 0.8        # I_zz / m as this times the points' mean squared horizontal radius
CONTACT_SUBSTEPS = 16     # per recorded step: 1/240 s at 15 Hz (model.contact_substeps' default)
AT_REST = 1e-8            # m/s and rad/s: below both a one-object step takes the motion away at once


def prior_changes(kind: str, linear_velocity: torch.Tensor, angular_velocity: torch.Tensor, dt: float,
                  friction: float, gravity: float = 9.81) -> torch.Tensor | None:
    """linear_velocity, angular_velocity: (..., 3) SI, world frame -> (..., 12) [dv, dw, dp, dtheta] SI,
    or None for ``kind="none"``."""
    if kind == "none":
        return None
    if kind not in PRIORS:
        raise ValueError(f"unknown prior '{kind}'; use one of {', '.join(PRIORS)}")
    v, w = linear_velocity, angular_velocity
    dv, dw, dp, dtheta = torch.zeros_like(v), torch.zeros_like(w), v * dt, w * dt
    if kind == "kinematic":
        return torch.cat([dv, dw, dp, dtheta], dim=-1)
    decel = max(abs(float(friction) * float(gravity)), 1e-9)
    u = v[..., :2]
    speed = torch.linalg.vector_norm(u, dim=-1, keepdim=True)
    direction = u / speed.clamp_min(1e-9)
    tau = torch.minimum(torch.full_like(speed, dt), speed / decel)  # sliding time within the step
    dv_xy = -decel * tau * direction
    dp_xy = (speed * tau - 0.5 * decel * tau * tau) * direction
    if kind == "coulomb":  # vertical motion and spin stay kinematic
        return torch.cat([dv_xy, dv[..., 2:], dw, dp_xy, dp[..., 2:], dtheta], dim=-1)
    t_stop = (speed / decel).clamp_min(1e-9)
    wz = w[..., 2:3]
    return torch.cat([dv_xy, -v[..., 2:3], -w[..., :2], -wz * tau / t_stop,
                      dp_xy, torch.zeros_like(speed), torch.zeros_like(u), wz * tau - wz * tau * tau / (2 * t_stop)], dim=-1)


def contact_geometry(points: torch.Tensor, touching: torch.Tensor | None = None, footprint: str = "spread") -> torch.Tensor:
    """points (B, N, 3) world-oriented body frame (centre of mass at the origin), metres ->
    (B, 4 * K + 2): the K lowest points' offsets (K x 3), their weights (K, summing to 1), I_zz / m, and
    the height of the centre of mass above the lowest point. ``touching`` (B, N) bool: the points that may
    carry the weight (default: within SUPPORT_DEPTH of the lowest; studies try other footprints).
    ``footprint`` (``model.contact_footprint``): how the K points are chosen among them, "spread" or "area"
    (see ``FOOTPRINTS``)."""
    if footprint not in FOOTPRINTS:
        raise ValueError(f"unknown footprint '{footprint}'; use one of {', '.join(FOOTPRINTS)}")
    B, N, _ = points.shape
    if (B == 1 and touching is None and footprint == "spread" and points.dtype == torch.float32
            and points.device.type == "cpu" and not (torch.is_grad_enabled() and points.requires_grad)):
        return _contact_geometry_one(points)
    z = points[..., 2]
    zmin = z.min(dim=1, keepdim=True).values
    if touching is None:
        touching = z <= zmin + SUPPORT_DEPTH
    xy = points[..., :2]
    if footprint == "area" and N >= 4:  # the rule picks four points
        index, fresh = _largest_area(xy, touching)
    else:
        index, fresh = _spread(xy, touching, min(SUPPORT_POINTS, N))
    support = torch.gather(points, 1, index[..., None].expand(-1, -1, 3))
    weights = fresh.to(points.dtype)
    weights = weights / weights.sum(dim=1, keepdim=True)
    spin_inertia = SPIN_INERTIA * (xy ** 2).sum(-1).mean(dim=1, keepdim=True)
    return torch.cat([support.reshape(B, -1), weights, spin_inertia.clamp_min(1e-8), -zmin], dim=1)


@np.errstate(invalid="ignore", over="ignore")  # as quiet as torch on a cloud a caller did not check
def _contact_geometry_one(points: torch.Tensor) -> torch.Tensor:
    """``contact_geometry`` of one cloud (1, N, 3) float32, spread footprint, on numpy: the same float32
    operations in the same order, to the bit (a test compares them), at about half the cost of the loop of
    tiny tensor operations (one new mesh's prediction pays it once)."""
    p = points[0].numpy()
    z = p[:, 2]
    zmin = z.min()
    touching = z <= zmin + np.float32(SUPPORT_DEPTH)
    # Only the touching points (a few of the cloud) take part: the others' distance is -1, below any touching
    # one's (>= 0), so the picks, the first of equals included, are those over the whole cloud. None touches
    # only in a cloud with no finite lowest point: then the whole-cloud loop picks point 0 four times, as this.
    touch = np.flatnonzero(touching) if touching.any() else np.zeros(1, dtype=np.int64)
    xy = p[touch, :2]
    distance = np.full(len(touch), np.float32(np.inf))
    pick = int(np.argmax((xy ** 2).sum(-1)))
    chosen, fresh = [], []
    for i in range(min(SUPPORT_POINTS, len(p))):
        chosen.append(int(touch[pick]))
        fresh.append(bool(distance[pick] > 0) if i else True)  # repeats weigh nothing
        distance = np.minimum(distance, ((xy - xy[pick]) ** 2).sum(-1))
        pick = int(np.argmax(distance))
    weights = np.array(fresh, dtype=np.float32)
    weights = weights / weights.sum(dtype=np.float32)
    # the mean over the cloud in torch: its reduction order, not numpy's pairwise one, to the bit
    spin_inertia = SPIN_INERTIA * (points[0, :, :2] ** 2).sum(-1).mean()
    tail = np.array([max(float(spin_inertia), 1e-8), -zmin], dtype=np.float32)
    return torch.from_numpy(np.concatenate([p[chosen].reshape(-1), weights, tail])[None])


def _spread(xy: torch.Tensor, touching: torch.Tensor, k: int) -> tuple[torch.Tensor, torch.Tensor]:
    """k touching points spread over the footprint by farthest-point sampling in the plane, so a large flat
    face keeps its extent and its centre -> (indices (B, k), whether each adds a new point (B, k)). It starts
    from the touching point farthest from the vertical through the centre of mass, so the same cloud listed
    in another order gets the same footprint."""
    distance = torch.where(touching, torch.full_like(xy[..., 0], float("inf")), torch.full_like(xy[..., 0], -1.0))
    pick = torch.argmax(((xy ** 2).sum(-1)).masked_fill(~touching, -1.0), dim=1)
    chosen, fresh = [], []
    for i in range(k):
        chosen.append(pick)
        gained = torch.gather(distance, 1, pick[:, None])[:, 0]
        fresh.append(gained > 0 if i else torch.ones_like(gained, dtype=torch.bool))  # repeats weigh nothing
        here = torch.gather(xy, 1, pick[:, None, None].expand(-1, 1, 2))
        distance = torch.minimum(distance, ((xy - here) ** 2).sum(-1).masked_fill(~touching, -1.0))
        pick = torch.argmax(distance, dim=1)
    return torch.stack(chosen, dim=1), torch.stack(fresh, dim=1)


def _largest_area(xy: torch.Tensor, touching: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """4 touching points spanning the largest area, greedily, as Bullet's contact manifold keeps its points:
    the one farthest from the vertical through the centre of mass, the one farthest from it, then the
    farthest on each side of the line between them -> (indices (B, 4), whether each adds area (B, 4)).
    Farthest-point sampling finds two corners of a box's face and then the middles of its long edges; this
    finds all four (docs/research/contact-prior.md)."""
    at = lambda i: torch.gather(xy, 1, i[:, None, None].expand(-1, 1, 2))[:, 0]  # noqa: E731
    first = torch.argmax((xy ** 2).sum(-1).masked_fill(~touching, -1.0), dim=1)
    second = torch.argmax(((xy - at(first)[:, None]) ** 2).sum(-1).masked_fill(~touching, -1.0), dim=1)
    origin, along = at(first), at(second) - at(first)
    # twice the area of the triangle (first, second, point), signed by the side of the line it lies on
    side = along[:, None, 0] * (xy[..., 1] - origin[:, None, 1]) - along[:, None, 1] * (xy[..., 0] - origin[:, None, 0])
    third = torch.argmax(side.masked_fill(~touching, -float("inf")), dim=1)
    fourth = torch.argmin(side.masked_fill(~touching, float("inf")), dim=1)
    length = torch.linalg.vector_norm(along, dim=-1)
    area3, area4 = (torch.gather(side, 1, i[:, None])[:, 0] for i in (third, fourth))
    # a point within 1 mm of the line adds no area: a line contact keeps its two ends
    fresh = torch.stack([torch.ones_like(length, dtype=torch.bool), length > 1e-9,
                         area3 > 1e-3 * length, -area4 > 1e-3 * length], dim=1)
    return torch.stack([first, second, third, fourth], dim=1), fresh


def contact_changes(linear_velocity: torch.Tensor, angular_velocity: torch.Tensor, orientation: torch.Tensor,
                    geometry: torch.Tensor, dt: float, friction: float, gravity: float = 9.81,
                    substeps: int = CONTACT_SUBSTEPS) -> torch.Tensor:
    """Velocities (B, T, 3) SI, orientation (B, T, 4) xyzw since the points were taken, geometry from
    ``contact_geometry`` -> (B, T, 12) [dv, dw, dp, dtheta] SI over one step dt (see the module docstring),
    integrated in ``substeps`` sub-steps (``model.contact_substeps``).

    Horizontal vectors are complex numbers x + iy: a turn by yaw is a product with exp(i yaw), the velocity
    of a point r of a body spinning at w_z is u + i w_z r, and the vertical torque r x f is Im(conj(r) f);
    half the tensor operations of x/y pairs, which matters in a loop of small tensors."""
    B, T = linear_velocity.shape[:2]
    if B == 1 and T == 1 and linear_velocity.device.type == "cpu" and not torch.is_grad_enabled():
        # One object, one step, no gradient: a one-at-a-time roll-out. The same arithmetic on Python
        # numbers costs ~0.1 ms where a loop of tiny tensor operations costs ~2 ms (tests compare them).
        out = _contact_changes_one(linear_velocity[0, 0].tolist(), angular_velocity[0, 0].tolist(),
                                   orientation[0, 0].tolist(), geometry[0].tolist(), dt, friction, gravity, substeps)
        return torch.tensor(out, dtype=linear_velocity.dtype).reshape(1, 1, 12)
    if not torch.is_grad_enabled():
        # Without gradient (roll-outs, evaluation), as on the one-object path: a body at rest is stopped
        # within the step, and the sub-steps run on the moving (sequence, step) pairs only; in a 3 s batch
        # most pairs rest. Training keeps the sub-steps everywhere (the same numbers to ~10 x AT_REST).
        v, w = linear_velocity, angular_velocity
        rest = (torch.hypot(v[..., 0], v[..., 1]) < AT_REST) & (w[..., 2].abs() < AT_REST)
        if rest.any():
            out = torch.cat([-v, -w, torch.zeros_like(v), torch.zeros_like(w)], dim=-1)
            b, t = (~rest).nonzero(as_tuple=True)
            if len(b):
                out[b, t] = _contact_substeps(v[b, t][:, None], w[b, t][:, None], orientation[b, t][:, None],
                                              geometry[b], dt, friction, gravity, substeps)[:, 0]
            return out
    return _contact_substeps(linear_velocity, angular_velocity, orientation, geometry, dt, friction, gravity, substeps)


def _contact_substeps(linear_velocity: torch.Tensor, angular_velocity: torch.Tensor, orientation: torch.Tensor,
                      geometry: torch.Tensor, dt: float, friction: float, gravity: float,
                      substeps: int = CONTACT_SUBSTEPS) -> torch.Tensor:
    """``contact_changes`` by its ``substeps`` sub-steps, for every (sequence, step) pair."""
    B, T = linear_velocity.shape[:2]
    K = (geometry.shape[1] - 2) // 4
    support = geometry[:, : 3 * K].reshape(B, 1, K, 3)
    base_weights = geometry[:, 3 * K : 4 * K].reshape(B, 1, K)
    spin_inertia = geometry[:, 4 * K].reshape(B, 1)
    height = geometry[:, 4 * K + 1].reshape(B, 1, 1)
    footprint = rotate(orientation[:, :, None, :], support)  # (B, T, K, 3) now
    r = torch.complex(footprint[..., 0], footprint[..., 1])  # (B, T, K)
    centre = (base_weights * r).sum(-1, keepdim=True)
    decel = max(abs(float(friction) * float(gravity)), 1e-9)
    h = dt / substeps
    slip_scale = decel * h  # below this slip speed friction scales down, so the body rests instead of chattering
    lean = PRESSURE_LEAN * float(friction) * height  # (B, 1, 1)
    v, w = linear_velocity, angular_velocity
    u0 = torch.complex(v[..., 0], v[..., 1])[..., None]  # (B, T, 1)
    om0 = w[..., 2:3]
    u, om = u0, om0
    # Pressure: the base weights tilted linearly across the footprint so that the centre of pressure lies
    # under the centre of mass (moment balance), leaning towards the travel while sliding. The 2 x 2
    # spread of the footprint (regularised by 1 mm^2 for line or point contacts) gives the tilt.
    offset = r - centre
    ox, oy = offset.real, offset.imag
    cxx = (base_weights * ox * ox).sum(-1, keepdim=True) + 1e-6
    cyy = (base_weights * oy * oy).sum(-1, keepdim=True) + 1e-6
    cxy = (base_weights * ox * oy).sum(-1, keepdim=True)
    det = cxx * cyy - cxy * cxy
    # The pressure for the whole step, from the travel at its start: the lean changes little within 1/15 s,
    # and this keeps the sub-step loop to a few operations (it dominates a one-object roll-out's cost).
    speed = u.abs()
    moving = (speed / slip_scale).clamp(max=1.0)
    shift = moving * lean * (u / speed.clamp_min(1e-9)) - centre
    ax = (cyy * shift.real - cxy * shift.imag) / det
    ay = (cxx * shift.imag - cxy * shift.real) / det
    weights = base_weights * (1.0 + ox * ax + oy * ay).clamp_min(0.0)
    weights = weights / weights.sum(-1, keepdim=True).clamp_min(1e-12)
    stiffness = decel * h / spin_inertia[..., None]
    # Below `stick` friction scales down with the slip, so a stopping point rests instead of chattering. A
    # sub-step then removes the slip over the footprint's effective mass (1 + sum w r^2 / I per unit mass):
    # at slip_scale alone, a contact far from the vertical through the centre of mass overshot, and a body
    # at rest swapped ever larger slide and spin between sub-steps (x4 per two at r^2 / I = 4).
    stick = slip_scale * (1.0 + (weights * (r.abs() ** 2)).sum(-1, keepdim=True) / spin_inertia[..., None])
    # The loop runs once per sub-step on small tensors, so its cost is the number of operations: a point r
    # of a body spinning at w_z moves at u + w_z i r, so i r is what is carried and turned; positions and
    # yaw are summed and scaled by the sub-step once, at the end.
    spun_r = 1j * r
    unit = torch.ones_like(om0)
    u_sum, om_sum = torch.zeros_like(u0), torch.zeros_like(om0)
    for _ in range(substeps):
        rel = u + om * spun_r
        # min(slip / stick, 1) / slip: full friction above the stick speed, scaled down with the slip below
        pull = rel * (weights / torch.maximum(rel.abs(), stick))
        u = u - decel * h * pull.sum(-1, keepdim=True)  # force per unit mass
        spun = om - stiffness * (spun_r.conj() * pull).sum(-1, keepdim=True).real  # Re(conj(i r) f) = Im(conj(r) f)
        om = torch.where(spun * om < 0, 0.0, spun)  # friction stops a spin, never reverses it
        u_sum = u_sum + u
        om_sum = om_sum + om
        spun_r = spun_r * torch.polar(unit, om * h)
    dp, yaw = u_sum * h, om_sum * h
    zeros1 = torch.zeros_like(om0)
    du = u - u0
    return torch.cat([du.real, du.imag, -v[..., 2:3], -w[..., :2], om - om0,
                      dp.real, dp.imag, zeros1, zeros1, zeros1, yaw], dim=-1)


def _contact_changes_one(v: list, w: list, q: list, geometry: list, dt: float, friction: float,
                         gravity: float, substeps: int = CONTACT_SUBSTEPS) -> list:
    """``contact_changes`` for one object and one step on Python numbers (complex for horizontal vectors),
    operation for operation: the 12 changes as a list."""
    if math.hypot(v[0], v[1]) < AT_REST and abs(w[2]) < AT_REST:
        # At rest (half the steps of a 3 s roll-out): friction takes what is left of the motion away within
        # the step. The sub-steps would give changes within about 10 x AT_REST of these (spin and yaw most;
        # measured over 300 resting states, the tests allow 100 x): far below anything a roll-out reports.
        return [-v[0], -v[1], -v[2], -w[0], -w[1], -w[2], 0.0, 0.0, 0.0, 0.0, 0.0, 0.0]
    K = (len(geometry) - 2) // 4
    qx, qy, qz, qw = q
    r = []
    for k in range(K):  # rotate the support point by q: x + w t + u x t, t = 2 u x x
        x, y, z = geometry[3 * k : 3 * k + 3]
        tx, ty, tz = 2.0 * (qy * z - qz * y), 2.0 * (qz * x - qx * z), 2.0 * (qx * y - qy * x)
        r.append(complex(x + qw * tx + (qy * tz - qz * ty), y + qw * ty + (qz * tx - qx * tz)))
    base = geometry[3 * K : 4 * K]
    spin_inertia, height = geometry[4 * K], geometry[4 * K + 1]
    centre = sum(b * rk for b, rk in zip(base, r))
    decel = max(abs(float(friction) * float(gravity)), 1e-9)
    h = dt / substeps
    slip_scale = decel * h
    lean = PRESSURE_LEAN * float(friction) * height
    u0, om0 = complex(v[0], v[1]), w[2]
    u, om, dp, yaw = u0, om0, 0j, 0.0
    offset = [rk - centre for rk in r]
    cxx = sum(b * o.real * o.real for b, o in zip(base, offset)) + 1e-6
    cyy = sum(b * o.imag * o.imag for b, o in zip(base, offset)) + 1e-6
    cxy = sum(b * o.real * o.imag for b, o in zip(base, offset))
    det = cxx * cyy - cxy * cxy
    speed = abs(u)
    moving = min(speed / slip_scale, 1.0)
    shift = moving * lean * (u / max(speed, 1e-9)) - centre
    ax = (cyy * shift.real - cxy * shift.imag) / det
    ay = (cxx * shift.imag - cxy * shift.real) / det
    weights = [b * max(1.0 + o.real * ax + o.imag * ay, 0.0) for b, o in zip(base, offset)]
    total = max(sum(weights), 1e-12)
    weights = [x / total for x in weights]
    stiffness = decel * h / spin_inertia
    stick = slip_scale * (1.0 + sum(wk * abs(rk) ** 2 for wk, rk in zip(weights, r)) / spin_inertia)
    pairs = [(wk, rk) for wk, rk in zip(weights, r) if wk > 0.0]  # a weightless point pulls nothing
    for _ in range(substeps):
        pull, torque = 0j, 0.0
        for wk, rk in pairs:
            rel = u + 1j * om * rk
            slip = abs(rel)
            pk = wk * rel / (slip if slip > stick else stick)  # min(slip / stick, 1) / slip
            pull += pk
            torque += rk.real * pk.imag - rk.imag * pk.real  # Im(conj(r) f)
        u = u - decel * h * pull
        spun = om - stiffness * torque
        om = 0.0 if spun * om < 0 else spun
        dp = dp + u * h
        turn = om * h
        yaw += turn
        if turn:
            spin = complex(math.cos(turn), math.sin(turn))
            pairs = [(wk, rk * spin) for wk, rk in pairs]
    du = u - u0
    return [du.real, du.imag, -v[2], -w[0], -w[1], om - om0, dp.real, dp.imag, 0.0, 0.0, 0.0, yaw]


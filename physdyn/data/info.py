"""A human summary of a store (`physdyn data info`)."""

from __future__ import annotations

import numpy as np

from physdyn.data.store import SPLIT_NAMES, StoreData


def _stats(x: np.ndarray) -> dict:
    if len(x) == 0:
        return {}
    return {"mean": float(np.mean(x)), "median": float(np.median(x)), "min": float(np.min(x)), "max": float(np.max(x))}


SLIDING_SPEED = 0.05  # m/s: a recorded step with |v_xy| above this is sliding
FAITHFUL_CHATTER = 0.15  # rad/s: a store above this carries contact noise (conventions: "Contact noise")


def tilt_chatter(d: StoreData) -> float | None:
    """The store's contact noise (conventions): the median, over non-toppling simulations with at least two
    sliding steps (|v_xy| > 5 cm/s), of the median |w_xy| (rad/s, world frame) over those steps. A sliding
    object that does not topple should not spin about a horizontal axis; PyBullet's contact chatter at a
    coarse physics step makes it do so. None when no simulation qualifies."""
    speed = np.linalg.norm(d.linear_velocity[:, :2], axis=1)
    tilt_spin = np.linalg.norm(d.angular_velocity[:, :2], axis=1)
    per_sim = []
    for i in np.flatnonzero(~d.toppled.astype(bool)):
        frames = slice(d.start[i], d.start[i + 1])
        sliding = speed[frames] > SLIDING_SPEED
        if sliding.sum() >= 2:
            per_sim.append(np.median(tilt_spin[frames][sliding]))
    return float(np.median(per_sim)) if per_sim else None


def summarize(d: StoreData) -> dict:
    cat_of_sim = d.sim_category()
    shape_split = np.zeros(d.num_shapes, dtype=int)
    shape_split[d.shape_id] = d.split
    lengths = d.lengths()
    v0 = np.linalg.norm(d.linear_velocity[d.start[:-1]], axis=1)
    w0 = np.linalg.norm(d.angular_velocity[d.start[:-1]], axis=1)
    categories = {}
    for c, name in enumerate(d.category_names):
        sims = cat_of_sim == c
        categories[name] = {
            "shapes": {SPLIT_NAMES[s]: int(np.sum((d.category == c) & (shape_split == s))) for s in SPLIT_NAMES},
            "sims": {SPLIT_NAMES[s]: int(np.sum(sims & (d.split == s))) for s in SPLIT_NAMES},
            "topple_fraction": float(np.mean(d.toppled[sims])) if sims.any() else None,
            "length_steps": _stats(lengths[sims]),
        }
    out = {
        "store": d.url,
        "rate_hz": d.rate_hz,
        "shapes": d.num_shapes,
        "sims": d.num_sims,
        "frames": int(d.start[-1]),
        "topple_fraction": float(np.mean(d.toppled)) if d.num_sims else None,
        "categories": categories,
        "length_seconds": _stats(lengths / d.rate_hz),
        "initial_speed_m_s": _stats(v0),
        "initial_spin_rad_s": _stats(w0),
        "friction": _stats(d.friction),
        "mass_kg": _stats(d.mass),
        "physics": d.attrs.get("physics", {}),
        "mass_method": d.attrs.get("config", {}).get("mass", {}).get("method", "exact"),
        "skipped_shapes": len(d.attrs.get("skipped", [])),
        "tilt_chatter_rad_s": tilt_chatter(d),
    }
    if "ensemble" in d.attrs:  # members per push, steps, seconds and the uncertainty, as simulated
        steps = d.extra.get("ensemble/topple_step", np.zeros((0, 0)))
        out["ensemble"] = {**d.attrs["ensemble"], "pushes": len(steps),
                           "topple_fraction": float(np.mean(steps >= 0)) if steps.size else None}
    if "shapes/exact_mass" in d.extra and out["mass_method"] != "exact":
        exact = d.extra["shapes/exact_mass"]
        out["voxel_vs_exact_mass_error"] = _stats(np.abs(d.mass - exact) / exact)
        if "shapes/exact_inertia_diag" in d.extra:
            ex_i = d.extra["shapes/exact_inertia_diag"]
            out["voxel_vs_exact_inertia_error"] = _stats(np.abs(d.inertia_diag - ex_i).max(axis=1) / ex_i.max(axis=1))
    return out


def format_summary(s: dict) -> str:
    def fmt(st: dict, unit: str = "", digits: int = 2) -> str:
        if not st:
            return "-"
        return (f"mean {st['mean']:.{digits}f}{unit}, median {st['median']:.{digits}f}{unit}, "
                f"range {st['min']:.{digits}f}-{st['max']:.{digits}f}{unit}")

    lines = [
        f"store      {s['store']}",
        f"rate       {s['rate_hz']:g} Hz",
        f"totals     {s['shapes']} shapes, {s['sims']} simulations, {s['frames']} frames; "
        f"{100 * (s['topple_fraction'] or 0):.1f} % topple",
        "",
        f"{'category':<12} {'shapes train/val/test':>22} {'sims train/val/test':>22} {'topple':>7} {'mean steps':>10}",
    ]
    for name, c in s["categories"].items():
        sh, si = c["shapes"], c["sims"]
        topple = "-" if c["topple_fraction"] is None else f"{100 * c['topple_fraction']:.1f}%"
        mean_len = c["length_steps"].get("mean", 0.0)
        lines.append(f"{name:<12} {sh['train']:>10}/{sh['val']}/{sh['test']:<6} {si['train']:>10}/{si['val']}/{si['test']:<6}"
                     f" {topple:>7} {mean_len:>10.1f}")
    lines += [
        "",
        f"duration   {fmt(s['length_seconds'], ' s')}",
        f"v0         {fmt(s['initial_speed_m_s'], ' m/s')}",
        f"omega0     {fmt(s['initial_spin_rad_s'], ' rad/s')}",
        f"friction   {fmt(s['friction'], '', 3)} (effective Coulomb coefficient)",
        f"mass       {fmt(s['mass_kg'], ' kg', 4)} ({s['mass_method']} mass properties)",
    ]
    if "voxel_vs_exact_mass_error" in s:
        lines.append(f"voxel vs exact mass error     {fmt({k: 100 * v for k, v in s['voxel_vs_exact_mass_error'].items()}, ' %')}")
    if "voxel_vs_exact_inertia_error" in s:
        lines.append(f"voxel vs exact inertia error  {fmt({k: 100 * v for k, v in s['voxel_vs_exact_inertia_error'].items()}, ' %')}")
    chatter = s.get("tilt_chatter_rad_s")
    if chatter is not None:
        verdict = "faithful" if chatter < FAITHFUL_CHATTER else (
            "NOISY: models must learn contact chatter; simulate at physics.time_step=0.00104167 (1/960 s)")
        lines.append(f"contact    tilt chatter {chatter:.3f} rad/s (median |w_xy| of non-toppling sims while sliding; "
                     f"< {FAITHFUL_CHATTER} is faithful): {verdict}")
    phys = s["physics"]
    if phys:
        lines.append("physics    " + ", ".join(f"{k}={v:g}" if isinstance(v, float) else f"{k}={v}" for k, v in phys.items()))
    ens = s.get("ensemble")
    if ens:
        spread = ", ".join(f"{k}={v:g}" for k, v in ens["uncertainty"].items())
        topple = "-" if ens["topple_fraction"] is None else f"{100 * ens['topple_fraction']:.1f} % topple"
        lines.append(f"ensemble   {ens['members']} members per push ({ens['pushes']} pushes), {ens['steps']} steps "
                     f"({ens['seconds']:g} s) each, {topple}; uncertainty {spread}")
    if s["skipped_shapes"]:
        lines.append(f"skipped    {s['skipped_shapes']} unusable shapes (listed in the store's 'skipped' attribute)")
    return "\n".join(lines)

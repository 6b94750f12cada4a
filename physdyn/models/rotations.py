"""Rotation maths on torch tensors of scalar-last (x, y, z, w) quaternions, for code that stays on the
device inside a loop (roll-outs, priors); ``physdyn.geometry.rotations`` is the numpy twin."""

from __future__ import annotations

import torch


def quat_multiply(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """Hamilton product a * b (apply b, then a), broadcasting over leading dimensions."""
    ax, ay, az, aw = a.unbind(-1)
    bx, by, bz, bw = b.unbind(-1)
    return torch.stack([aw * bx + ax * bw + ay * bz - az * by,
                        aw * by - ax * bz + ay * bw + az * bx,
                        aw * bz + ax * by - ay * bx + az * bw,
                        aw * bw - ax * bx - ay * by - az * bz], dim=-1)


def rotvec_to_quat(rotvec: torch.Tensor) -> torch.Tensor:
    """Exp: axis-angle (..., 3) -> unit quaternion (..., 4); a series near zero keeps small angles exact."""
    angle = torch.linalg.vector_norm(rotvec, dim=-1, keepdim=True)
    half = 0.5 * angle
    small = angle < 1e-4
    # sin(a/2)/a: its Taylor series below 1e-4 rad, where the quotient loses digits
    scale = torch.where(small, 0.5 - angle * angle / 48.0, torch.sin(half) / torch.where(small, torch.ones_like(angle), angle))
    return torch.cat([rotvec * scale, torch.cos(half)], dim=-1)


def rotate(q: torch.Tensor, x: torch.Tensor) -> torch.Tensor:
    """Rotate vectors x (..., 3) by unit quaternions q (..., 4), broadcasting."""
    u, x = torch.broadcast_tensors(q[..., :3], x)
    t = 2.0 * torch.cross(u, x, dim=-1)
    return x + q[..., 3:4] * t + torch.cross(u, t, dim=-1)


def rotation_6d(q_xyzw: torch.Tensor) -> torch.Tensor:
    """(..., 4) xyzw -> (..., 6): the first two columns of the rotation matrix, a continuous representation
    of a rotation (Zhou et al., CVPR 2019), unlike a quaternion's sign or an axis-angle's wrap-around."""
    q = q_xyzw / torch.linalg.vector_norm(q_xyzw, dim=-1, keepdim=True).clamp_min(1e-12)
    x, y, z, w = q.unbind(-1)
    col0 = torch.stack([1 - 2 * (y * y + z * z), 2 * (x * y + z * w), 2 * (x * z - y * w)], dim=-1)
    col1 = torch.stack([2 * (x * y - z * w), 1 - 2 * (x * x + z * z), 2 * (y * z + x * w)], dim=-1)
    return torch.cat([col0, col1], dim=-1)

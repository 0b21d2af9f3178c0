"""Differentiable, batched torch twin of `mogo.motion.features.features_to_joints`.

Training needs joint positions recovered from predicted features (the VQ's joint-position loss,
MPJPE), with gradients, on whole batches. The recovery must be the runtime's exactly, root
integration included: the root yaw half-angle a[t] is the sum of feature 0 over frames < t, the
root XZ the sum of the frame velocities (features 1:3 of the previous frame) turned by -2 a[t]
about +Y, and every joint's root-relative position is turned the same way and moved to the root.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import Tensor


def num_joints_for_feature_dim(dim: int) -> int:
    """J of the HumanML3D layout with D = 4 + 9 (J - 1) + 3 J + 4 = 12 J - 1 dims."""
    if dim < 23 or (dim + 1) % 12:
        raise ValueError(f"{dim}-dim features are not a HumanML3D-layout motion (12 J - 1 dims)")
    return (dim + 1) // 12


def features_to_joints(features: Tensor) -> Tensor:
    """Un-normalised features (..., T, D) -> joint positions (..., T, J, 3), same dtype."""
    J = num_joints_for_feature_dim(features.shape[-1])
    half_angle = F.pad(torch.cumsum(features[..., :-1, 0], dim=-1), (1, 0))  # (..., T)
    cos, sin = torch.cos(2 * half_angle), torch.sin(2 * half_angle)

    def unturn(x: Tensor, z: Tensor, c: Tensor, s: Tensor) -> tuple[Tensor, Tensor]:
        """Turn (x, z) by -2a about +Y, given c, s = cos 2a, sin 2a."""
        return x * c - z * s, x * s + z * c

    velocity = F.pad(features[..., :-1, 1:3], (0, 0, 1, 0))  # (..., T, 2): v[0] = 0
    step_x, step_z = unturn(velocity[..., 0], velocity[..., 1], cos, sin)
    root_x, root_z = torch.cumsum(step_x, dim=-1), torch.cumsum(step_z, dim=-1)  # (..., T)
    root = torch.stack([root_x, features[..., 3], root_z], dim=-1)  # (..., T, 3)

    relative = features[..., 4 : 4 + 3 * (J - 1)].unflatten(-1, (J - 1, 3))  # (..., T, J-1, 3)
    x, z = unturn(relative[..., 0], relative[..., 2], cos[..., None], sin[..., None])
    joints = torch.stack([x + root_x[..., None], relative[..., 1], z + root_z[..., None]], dim=-1)
    return torch.cat([root[..., None, :], joints], dim=-2)

"""The grey network that uses the cameras' poses: 2D features of every grey view lifted into the
world-frame voxel grid along the camera rays, then the voxel networks' 3D CNN and heads.

A grey view says nothing about depth, but every voxel is seen by several views: where the object
really is, the views' features agree (they all show the same surface), and elsewhere each ray passes
a different background or part. So the multi-view network gives the 3D CNN, per voxel, the mean and
the variance of the features over the views that see it (and the share of views that do): the
variance is low on the object's surface, and the grid is in paper units as for depth, so counts and
lengths are read off it the same way. The temporal network lifts the frames of its one camera into
separate channels: the rays cross the chain's plane (the grid's y = 0), where the lifted image is
the chain drawn to scale, and which parts move together shows in how the channels differ.
"""

from __future__ import annotations

import torch
from torch import nn

from spare_twin.nets.blocks import InputNorm, task_heads, time_bin_frames, voxel_cnn, voxel_fc
from spare_twin.nets.geometry import lift
from spare_twin.nets.presets import NetConfig

#: Stands in for a view that does not see a voxel when the extremes over the views are taken.
UNSEEN_FILL = 1e4
#: Total stride of the view CNN: one feature per 2 x 2 pixels (about a voxel at the rig's distance).
VIEW_STRIDE = 2


class ViewFeatures(nn.Module):
    """A small 2D CNN shared by every view: (N, H, W) normalised grey -> (N, `out`, H/2, W/2).

    Three 3x3 convolutions (the first strided, the last dilated: about 13 pixels of context) and a
    1x1 to `out - 1` learned channels; the last channel is the grey value itself at the feature
    pixel's centre (its spread over the views is a direct photo-consistency cue)."""

    def __init__(self, out: int, width: int = 16):
        super().__init__()
        self.net = nn.Sequential(
            nn.Conv2d(1, width, 3, stride=VIEW_STRIDE, padding=1, bias=False),
            nn.BatchNorm2d(width),
            nn.ReLU(inplace=True),
            nn.Conv2d(width, width, 3, padding=1, bias=False),
            nn.BatchNorm2d(width),
            nn.ReLU(inplace=True),
            nn.Conv2d(width, width, 3, padding=2, dilation=2, bias=False),
            nn.BatchNorm2d(width),
            nn.ReLU(inplace=True),
            nn.Conv2d(width, out - 1, 1),
        )

    def forward(self, x):  # (N, H, W)
        f = self.net(x[:, None])
        grey = x[:, None, ::VIEW_STRIDE, ::VIEW_STRIDE]  # the pixel each feature is centred on
        return torch.cat([f, grey], 1)


class GreyLiftNet(nn.Module):
    """Grey views (mv: the V views of a time step; tmp: `grid.time_bins` evenly spaced frames of one
    camera) -> view features -> lifted into the grid -> 3D CNN -> count, 7-slot lengths (paper
    units) and, for mv with `predict_angles`, joint angles."""

    def __init__(self, cfg: NetConfig):
        super().__init__()
        self.cfg = cfg
        self.norm = InputNorm()
        c = cfg.lift_features
        self.views = ViewFeatures(c)
        per_view_stats = 4 if cfg.lift_extremes else 2
        cin = (per_view_stats * c if cfg.mode == "mv" else cfg.grid.time_bins * c) + 1
        self.cnn = voxel_cnn(cin, cfg.channels, stem=False)
        self.fc = voxel_fc(cfg.grid.cells, len(cfg.channels) - 1, cfg.fc_hidden, cfg.dropout)
        self.heads = task_heads(cfg, angles=cfg.predict_angles and cfg.mode == "mv")

    def grid_of(self, x, K, T_world_camera, print_scale) -> torch.Tensor:
        """(B, channels, Z, Y, X): the lifted features (see the module docstring)."""
        B = x.shape[0]
        if self.cfg.mode == "tmp":
            bins = self.cfg.grid.time_bins
            x = x[:, time_bin_frames(x.shape[1], bins)]
            K, T_world_camera = K.expand(B, bins, 3, 3), T_world_camera.expand(B, bins, 4, 4)
        V, H, W = x.shape[1:]
        f = self.views(self.norm(x).reshape(B * V, H, W))
        values, seen = lift(f.reshape(B, V, *f.shape[1:]), K, T_world_camera, print_scale, self.cfg.grid, VIEW_STRIDE)
        if self.cfg.mode == "tmp":
            channels = [values.reshape(B, -1, values.shape[-1]), seen[:, 0]]
        else:
            # values are 0 where a view does not see the voxel, so plain sums are sums over the seeing views
            count = seen.sum(1)
            mean = values.sum(1) / count.clamp_min(1.0)
            var = (values.square().sum(1) / count.clamp_min(1.0) - mean.square()).clamp_min(0.0)
            channels = [mean, var]
            if self.cfg.lift_extremes:
                # over the views that see the voxel: the minimum of a feature that marks the object is
                # the visual hull, crisp where the mean is blurred by the views that see past a thin link
                unseen = (1.0 - seen) * UNSEEN_FILL
                lowest = (values + unseen).min(1).values  # min(), not amin(): its backward is one scatter
                highest = (values - unseen).max(1).values
                none = count == 0
                channels += [lowest.masked_fill(none, 0.0), highest.masked_fill(none, 0.0)]
            channels.append(count / V)
        nx, ny, nz = self.cfg.grid.cells
        return torch.cat(channels, 1).reshape(B, -1, nz, ny, nx)

    def forward(self, x, K=None, T_world_camera=None, print_scale=None, **_):
        if K is None or T_world_camera is None or print_scale is None:
            raise ValueError("grey_lift needs K, T_world_camera and print_scale")
        h = self.fc(self.cnn(self.grid_of(x, K, T_world_camera, print_scale)))
        return {k: head(h) for k, head in self.heads.items()}

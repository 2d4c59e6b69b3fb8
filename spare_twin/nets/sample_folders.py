"""Folders of ready profile samples (the profile network's training input beside the rig's datasets):
their format, kinds and split codes. Light to import, so that a command can check a folder before
it loads torch.

Two commands write them, in the same format (`samples.npz`: `x`, `n`, `lengths`, `angles`, `split`;
`manifest.json`): `spare-twin dataset --handheld` (captures drawn the bench's way and observed as
`predict` observes them, `bench.handheld_samples`) and `spare-twin dataset --analytic-profiles`
(profiles drawn straight from the printed chain's geometry, `nets.profile_analytic`).
"""

from __future__ import annotations

#: The format of a folder of profile samples (its name is older than the analytic samples).
HANDHELD_FORMAT = "spare-twin hand-held profile samples 1"
#: The output kinds (the commands that write them).
HANDHELD_KIND = "dataset --handheld"
ANALYTIC_KIND = "dataset --analytic-profiles"
#: `split` codes in a sample folder's samples.npz.
SPLIT_CODES = {"train": 0, "val": 1}

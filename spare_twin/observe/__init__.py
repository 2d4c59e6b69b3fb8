"""Observation: any recording (training-rig render, hand-held render, imported real capture) into
the networks' input space. Sits between `capture` (poses, fusion, the object on the table) and
`nets`, so that neither of those needs the other.

`network_input.observe_recording` is the entry point (a Recording -> one `NetworkInput` per yaw
hypothesis); `canonical` finds the object frame and re-renders a recording into the training rig,
with `splat` drawing the object's points over the table."""

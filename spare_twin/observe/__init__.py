"""Observation: any recording (training-rig render, hand-held render, imported real capture) as what
the measurement and the networks read. Sits between `capture` (poses, fusion, the object on the
table) and `measure` / `nets` / `predict`.

Two inputs come out of it: the chain's points and profile, which the measurement and the yaw-free
profile network read (`views`: a recording folder as posed views in memory; `points`, `profile`,
`chain`: posed views -> the object's points -> the chain's profile), and the image networks' input
(`network_input.observe_recording`: a Recording -> one `NetworkInput` per yaw hypothesis, with
`canonical` finding the object frame and re-rendering a recording into the training rig, `splat`
drawing the object's points over the table). `spare_twin.predict` runs both."""

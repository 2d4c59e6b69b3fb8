"""Observation: any recording (training-rig render, hand-held render, imported real capture) into
the networks' input space. Sits between `capture` (poses, fusion, the object on the table) and
`nets`, so that neither of those needs the other."""

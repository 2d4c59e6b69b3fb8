"""Benchmarks that run several stages together, above `compare` in the layers.

`spare_twin.bench.sim2real` is the sim-to-real bench (`spare-twin bench sim2real`, docs/sim2real.md):
unseen printed objects captured with every effect of a real print and sensor, `predict`'s combined
answer, the measurement and each network scored on their own, in sim and in real. Its parts:
`settings` (what is captured, a seeded table), `capture` (drawing the captures), `scoring` (scores,
the table, its Markdown and plot) and `sim2real` (running it: resumable, objects in parallel).
"""

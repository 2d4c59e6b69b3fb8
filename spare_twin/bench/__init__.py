"""Every benchmark of `spare-twin bench`, one module each, above every stage in the layers (so a
benchmark may drive several stages together); `spare_twin/commands/bench.py` only parses and prints.

| `spare-twin bench` | module | measures |
|---|---|---|
| `dataset` | `dataset` | dataset images/s end to end (local and Ray) against pybullet's raw render loop |
| `capture` | `capture_registration` | registration accuracy and time on real RealSense frames; import, fusion speed |
| `nets` | `nets` | a network's inference samples/s and latency per sample |
| `training` | `training` | training samples/s per preset under thread / worker / memory-layout settings |
| `object` | `object` | seconds to build a 6-link object (geometry, object folder, whole CLI) |
| `live` | `live` | `live`'s latency, update interval and memory on a sweep replayed in real time |
| `sim2real` | `sim2real` | the sim-to-real table (docs/sim2real.md) |

The sim-to-real bench has parts of its own: `settings` (what is captured, a seeded table), `capture`
(drawing the captures), `scoring` (scores, the table, its Markdown and plot) and `sim2real` (running
it: resumable, objects in parallel).
"""

"""The pybullet twin: camera rigs, joint motion, rendering and sim-to-real options.

Modules are small and import pybullet only where they render (`twin.py`), so the rig and motion
code can be used (and tested) without a simulator.
"""

"""Sim vs real for printed objects: articulated registration of the twin to a cloud
(`articulated`), its refinement on depth (`depth_fit`), the comparison of one object
(`sim_vs_real`), tables over many (`table`) and the Rerun log (`rerun_log`); `inputs` checks what
they and the demo read and write before anything heavy is loaded."""

"""The whole study from one call: stages, plan, report.

Importing this package before torch makes torch's OpenMP threads wait passively
(``OMP_WAIT_POLICY=PASSIVE`` unless the environment sets it): libgomp's default lets an idle
thread spin, and where anything else shares the cores, two spinning training threads take the
CPU from each other. On a 2-core AVX2 AMD EPYC running other jobs, a float32 UNet step of the
tiny study took 1.7 s with spinning threads and 0.74 s without, with bit-identical weights
(``benchmarks/bench_cpu_training.py --settings``; benchmarks/README.md). libgomp reads the
setting once, when torch is first imported; a process that imported torch earlier keeps its own.
"""

import os

os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

"""How pcdof runs, decided in one place: process tuning (:mod:`.process`), threads and pools
(:mod:`.threads`), kernels run as tasks on those threads (:mod:`.tasks`), and the kernels' compilation and its
message (:mod:`.kernels`).

The stages say what they compute; nothing in a stage sets a thread count, starts a pool or compiles
ahead. Importing this package loads nothing heavy.
"""

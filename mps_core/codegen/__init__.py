"""Generated Python: the chart views' kernels from traced position functions (central
differences :mod:`.kernels`, exact derivatives :mod:`.exact_kernels`, the equations with the
effects folded in :mod:`.fused_kernels`) and the reactions' kernels (:mod:`.reaction_kernels`)."""

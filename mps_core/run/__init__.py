"""Running a model: the simulation's driver loop (:mod:`.simulation`) with its structure layer
(commands, impacts, :mod:`.structure_layer`), what it returns (:mod:`.trajectory`), many
scenes at once (:mod:`.batch`), a scene built and run (:mod:`.build`) and a run's progress
line (:mod:`.progress`)."""

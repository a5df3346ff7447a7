"""Files a command reads and writes: input files read with one clear error for each way they
can be wrong (:mod:`.inputs`), output paths checked before a run and written whole
(:mod:`.outputs`)."""

"""The Rerun view: a recording drawn and plotted (:mod:`.offline`), or the running node followed
live (:mod:`.live`)."""

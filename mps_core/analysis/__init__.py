"""What a run means for the building: the load report (:mod:`.loads`) and its command
``mps loads`` (:mod:`.loads_cli`); the envelope over many runs (:mod:`.sweep`) and ``mps sweep``
(:mod:`.sweep_cli`)."""

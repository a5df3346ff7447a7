"""The dynamics: the partial-system engine (Lagrange's equations of the second kind from the
partial systems, :mod:`.engine`) and the joints' reactions (:mod:`.reactions`)."""

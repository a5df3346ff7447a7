"""Names and wire: what the twin says and how it is encoded, defined once, no ROS.

The topics, types, frames, joints and wrenches (:mod:`.topics`), the CDR encoders of the
per-step messages (:mod:`.cdr`), a step's messages in publishing order (:mod:`.step_messages`),
the ``/tf`` frames and the markers (:mod:`.frames`, :mod:`.markers`, drawn from
:mod:`.drawing`), and the ``/diagnostics`` statuses (:mod:`.diagnostics`).
"""

"""MAVLink boards (flight controllers): the ``mavlink://`` link and the ``mavlink_vehicle``
host device (extra ``[mavlink]``, pymavlink)."""

"""``diffdrive``: wheel encoders and motors. The odometry and the emulated base
(:mod:`.encoders`), the device plugin (:mod:`.plugin`), its host node (:mod:`.node`) and its
pin-level model for simavr (:mod:`.pins`)."""

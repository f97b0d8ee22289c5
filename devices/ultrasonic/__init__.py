"""``hcsr04``: the HC-SR04 ultrasonic ranger. The ranger's conversions and its emulated model
(:mod:`.hcsr04`), the device plugin (:mod:`.plugin`), its host node (:mod:`.node`) and its
pin-level model for simavr (:mod:`.pins`)."""

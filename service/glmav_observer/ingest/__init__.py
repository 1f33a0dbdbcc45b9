"""MAVLink bytes -> typed samples in SI units (pure decode and convert; transport at the edge)."""

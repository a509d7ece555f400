"""pointillist's Mitsuba integrator plugins, one per module (see :mod:`plugins`)."""

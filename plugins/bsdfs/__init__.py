"""pointillist's Mitsuba bsdf plugins, one per module (see :mod:`plugins`)."""

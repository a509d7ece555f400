"""pointillist's Mitsuba sampler plugins, one per module (see :mod:`plugins`)."""

"""The named physical effects of the ToF simulator, one module each (see ``..registry``)."""

"""Action behaviours: each writes one velocity command per tick while it runs."""

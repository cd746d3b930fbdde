"""Condition behaviours that select controllers: SUCCESS means "my controller runs"."""

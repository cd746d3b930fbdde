"""Data-gathering behaviours: sensors -> blackboard (obstacles, pose, features).

They always return SUCCESS: a missing or stale sensor is the safety layer's business,
not a reason to stop gathering the others.
"""

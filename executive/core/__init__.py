"""Shared vocabulary of walkaround: frames, mission model, problems and XML loading.

This package imports nothing from ``behaviours``, ``sim2d`` or the top of ``executive``.
"""

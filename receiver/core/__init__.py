"""Shared foundation of every stage: frozen records (`records`), the one error type (`errors`),
the per-stage clock and budget statistics (`budget`), the protocol constants (`protocol`).
"""

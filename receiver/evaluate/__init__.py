"""Scoring a run against truth (`metrics`) and its PNG plots (`plots`).
"""

"""Decoding stage: OOK packets (`ook`) and their frame clock (`frameclock`), S2-PSK pairs
(`s2psk`), tone frequencies (`tone`), the per-light decoding policy (`policy`).
"""

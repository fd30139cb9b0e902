"""Decoding stage: OOK packets (`ook`) and their frame clock (`frameclock`), S2-PSK pairs
(`s2psk`) and every live pair's S2-PSK decoder sets (`pair_decoding`), tone frequencies
(`tone`), the per-light decoding policy (`policy`).
"""

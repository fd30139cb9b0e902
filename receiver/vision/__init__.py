"""Image stage: LED blobs (`detect`), row profiles (`profile`, `tone_profile`), envelope merge
across frames (`envelope`), frame-to-frame tracking (`track`), S2-PSK emitter pairs (`pairing`).
"""

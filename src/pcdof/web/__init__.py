"""The browser viewer (``pcdof view --serve``): the focal-plane scene and the live preview served by trame.

:mod:`pcdof.web.session` holds one frame's state and renders (no web code); :mod:`pcdof.web.app` is the
trame page around it.
"""

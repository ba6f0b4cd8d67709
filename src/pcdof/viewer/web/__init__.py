"""The browser viewer (``pcdof view --serve``): the focal-plane scene and the live preview served by trame.

:mod:`pcdof.viewer.web.session` holds one frame's state and renders (no web code); :mod:`pcdof.viewer.web.app`
is the trame page around it.
"""

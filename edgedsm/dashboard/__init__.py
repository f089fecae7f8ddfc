"""The operator's live plant dashboard (``edgedsm dashboard``): one page for every daemon of a plant.

Data flows one way: MQTT (``subscriber``) → parsed into the in-memory plant view (``plant``) and
the SQLite history (``history``) → served over HTTP with live updates by Server-Sent Events
(``server``). See ``docs/dashboard.md``.
"""

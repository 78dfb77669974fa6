"""The web diagnostics dashboard (``pyethercat web``, ``run --web``).

Needs the optional ``web`` dependencies (``pip install 'pyethercat[web]'``):
Starlette for the application, uvicorn to serve it, websockets for the live
channel. The charts are uPlot (MIT licence, ``static/LICENSE-uPlot.txt``),
shipped as a static file: nothing is fetched from the internet at run time.

- :mod:`~pyethercat.web.source`: the way to the master (control socket or in process);
- :mod:`~pyethercat.web.model`: snapshots to JSON (decoding happens here, not in the master);
- :mod:`~pyethercat.web.hub`: one poller at a bounded rate, fanned out to the browsers;
- :mod:`~pyethercat.web.security`: bind address, token, writes, CSP;
- :mod:`~pyethercat.web.app`: the Starlette application; :mod:`~pyethercat.web.server`: uvicorn.
"""

__all__: list[str] = []

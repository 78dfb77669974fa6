"""The device applications of a segment, called on ESC events.

A slave's device application (``sim.device.DeviceApp``) runs on events of its
ESC. Most events are rare (state changes, mailbox, power) and reach the one
application directly from its ESC. A completed output buffer happens every
cycle: :class:`DeviceApps` calls only the applications that asked for it
(``wants_output_events``), selected with one mask over the slaves whose
buffers completed in the frame.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from pyethercat.sim.device import DeviceApp

__all__ = ["DeviceApps"]

I64 = npt.NDArray[np.int64]


class DeviceApps:
    """Applications by slave index (see the module docstring)."""

    def __init__(self) -> None:
        self.apps: list[DeviceApp | None] = []
        #: Per slave: the application wants :meth:`DeviceApp.on_outputs` calls.
        self.wants_outputs = np.zeros(0, bool)
        self._any = False

    def add(self, app: DeviceApp | None) -> None:
        self.apps.append(app)
        self.wants_outputs = np.append(self.wants_outputs, bool(app is not None and app.wants_output_events))
        self._any = bool(self.wants_outputs.any())

    def outputs_completed(self, slaves: I64) -> None:
        """New complete output buffers of ``slaves`` (one frame's worth)."""
        if not self._any:
            return
        apps = self.apps
        for s in slaves[self.wants_outputs[slaves]].tolist():
            app = apps[s]
            if app is not None:
                app.on_outputs()

"""Live monitoring: follow a growing injection log and seismicity with the model, screen every
step and alert operators through plugins.

* :class:`Stage` (``stage.py``) -- the embeddable pipeline stage: samples and events in, model
  state, level changes and alerts out; atomic checkpoints and exact restarts.
* ``service.py`` -- the loop behind ``fault-screen monitor``: a source plugin feeding the stage,
  the outbox delivering its alerts, checkpoints, signals, idle exit.
* ``outbox.py`` -- durable alert outbox (SQLite); ``plugins.py`` -- entry-point discovery;
  ``seismicity.py`` -- growing catalogues, STA/LTA detections on an SDS archive or a SeedLink
  server, association with the model.
"""
from .stage import LEVELS, SampleBuffer, Stage, Update, alert_id, alert_payload  # noqa: F401
from .seismicity import CatalogFollower, SdsDetector, SeedLinkDetector, SeismicEvent, Site  # noqa: F401

__all__ = ["Stage", "Update", "SampleBuffer", "alert_id", "alert_payload", "LEVELS",
           "SeismicEvent", "Site", "CatalogFollower", "SdsDetector", "SeedLinkDetector"]

"""The bench: sessions, scenarios, recordings, step metrics, tuning.

Importing it registers the bench's config tables ([run], [link], [target], [tuning], [[scenario]]).
"""

from hilbench.bench import settings as _settings  # noqa: F401

import os

# headless rendering everywhere; torch stays on one thread (README, "Development")
os.environ.setdefault("SDL_VIDEODRIVER", "dummy")
os.environ.setdefault("SDL_AUDIODRIVER", "dummy")
os.environ.setdefault("MPLBACKEND", "Agg")

# hypothesis: a few examples per property in CI (the fuzz tests must stay fast); the thorough run is
# KIN_HYPOTHESIS_PROFILE=full (see the README's Development section)
try:
    from hypothesis import settings

    settings.register_profile("ci", max_examples=20, deadline=None)
    settings.register_profile("full", max_examples=300, deadline=None)
    settings.load_profile(os.environ.get("KIN_HYPOTHESIS_PROFILE", "ci"))
except ImportError:  # hypothesis is a dev extra; the fuzz tests import it themselves
    pass

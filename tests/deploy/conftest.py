"""Exports shared by the deployment tests (one per module run: an export drives the policy's
own evaluation episodes for its parity check)."""

import pytest


@pytest.fixture(scope="session")
def exported(tmp_path_factory):
    """``exported(model, switching)`` → the folder of that export (made once per session)."""
    from safeswitch.deploy.export import export

    made = {}

    def get(model="paper", switching=None):
        key = (model, switching)
        if key not in made:
            folder = tmp_path_factory.mktemp(f"export_{model}_{switching}")
            made[key] = export(model, folder, switching=switching, observations=4_000,
                               overwrite=True)  # fmt: skip
        return made[key].folder

    return get

"""What a fresh machine relies on: the locks, a quiet ``import wrl_jax``, a clear error when gymnax breaks,
and the contracts in docs/ equal to the team's copies.

``make run`` on a clean clone is walked by ``.ci/run`` itself (core install alone, tiny budget); these
tests keep the pieces it stands on from drifting.
"""

import re
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
LOCKS = ROOT / "requirements"


def _normal(name: str) -> str:
    return re.sub(r"[-_.]+", "-", name).lower()


def _locked(path: Path) -> dict[str, tuple[str, tuple[str, ...]]]:
    """``name -> (version, hashes)`` of a pip-compile style lock with ``--hash`` lines."""
    entries: dict[str, tuple[str, tuple[str, ...]]] = {}
    for block in re.split(r"\n(?=[A-Za-z0-9])", path.read_text()):
        match = re.match(r"([A-Za-z0-9][A-Za-z0-9._-]*)==(\S+)", block)
        if match:
            entries[_normal(match[1])] = (match[2], tuple(sorted(re.findall(r"--hash=(sha256:[0-9a-f]{64})", block))))
    return entries


def _requirement_names(requirements: list[str]) -> set[str]:
    return {_normal(re.match(r"[A-Za-z0-9._-]+", r)[0]) for r in requirements}


def test_locks_pin_every_package_with_hashes_and_core_is_a_subset_of_test():
    core, test = _locked(LOCKS / "core.txt"), _locked(LOCKS / "test.txt")
    assert core and test
    for name, (version, hashes) in {**core, **test}.items():
        assert hashes, f"{name}=={version} has no hash"
    for name, entry in core.items():
        assert test.get(name) == entry, f"{name}: core lock {entry[0]}, test lock {test.get(name, ('absent',))[0]}"


def test_the_installer_is_pinned_by_hash_and_the_makefile_falls_back_to_pip():
    """``make`` installs the locks with uv (requirements/uv.txt, every wheel's hash, no sdist) and with pip where
    uv cannot: both read the same lock with ``--require-hashes --no-deps``."""
    (version, hashes), = _locked(LOCKS / "uv.txt").values()
    assert re.fullmatch(r"\d+\.\d+\.\d+", version) and len(hashes) >= 10
    makefile = (ROOT / "Makefile").read_text()
    uv_line = next(line for line in makefile.splitlines() if line.startswith("install_lock"))
    assert "--require-hashes --no-deps" in uv_line and "$(PIP) $(LOCKED) -r $(1)" in makefile
    assert "--require-hashes --no-deps" in makefile.split("LOCKED :=")[1].splitlines()[0]


def test_locks_hold_what_pyproject_declares():
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    core, test = _locked(LOCKS / "core.txt"), _locked(LOCKS / "test.txt")
    build = _requirement_names(tomllib.loads((ROOT / "pyproject.toml").read_text())["build-system"]["requires"])
    assert _requirement_names(project["dependencies"]) | build <= set(core)
    extras = [r for name in ("dev", "notebooks", "sb3") for r in project["optional-dependencies"][name]]
    assert _requirement_names(extras) <= set(test)
    # gymnax imports six on `import gymnax` without declaring it: it must be ours to declare.
    assert "six" in _requirement_names(project["dependencies"])


def _python(code: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT, timeout=120)


def test_import_registers_names_and_starts_nothing():
    done = _python(
        "import sys, wrl_jax, gymnasium\n"
        "assert 'Warehouse-8x8-v0' in wrl_jax.registered_names()\n"
        "assert 'wrl_jax/Warehouse-8x8-v0' in gymnasium.registry\n"
        "print(sorted(m for m in ('jax', 'gymnax', 'flax', 'optax') if m in sys.modules))\n"
        "import gymnax\n"  # after wrl_jax, before any environment: gymnax still learns the names
        "assert 'wrl_jax/Fleet-12x12-v0' in gymnax.registered_envs\n"
    )
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip() == "[]"


def test_gymnax_learns_our_names_whichever_is_imported_first():
    done = _python(
        "import gymnax, wrl_jax\n"
        "assert 'wrl_jax/Fleet-12x12-v0' in gymnax.registered_envs\n"
        "env, params = gymnax.make('wrl_jax/Warehouse-8x8-v0')\n"
        "assert env.name == 'Warehouse-8x8-v0'\n"
    )
    assert done.returncode == 0, done.stderr
    done = _python(
        "import importlib.util, sys, wrl_jax\n"
        "env, params = wrl_jax.make('Warehouse-8x8-v0')\n"
        "assert importlib.util.find_spec('gymnax') is not None\n"  # a lookup alone leaves the import hook in place
        # the environment loaded gymnax's base modules alone, not gymnax's environments (seaborn, scipy...)
        "assert 'gymnax.environments.environment' in sys.modules\n"
        "assert not {'gymnax', 'gymnax.environments', 'seaborn'} & set(sys.modules)\n"
        "base = sys.modules['gymnax.environments.environment'].Environment\n"
        "import gymnax\n"
        "assert gymnax.make('wrl_jax/Warehouse-12x12-v0')[0].name == 'Warehouse-12x12-v0'\n"
        "assert isinstance(env, gymnax.environments.environment.Environment)\n"  # one base class, whoever came first
        "assert env.action_space(params).__class__ is gymnax.environments.spaces.Discrete\n"
        "assert gymnax.make('CartPole-v1')[0].name == 'CartPole-v1'\n"
        "assert gymnax.environments.environment.Environment is base\n"
        "assert issubclass(gymnax.environments.CartPole, base)\n"  # gymnax's own environments too
    )
    assert done.returncode == 0, done.stderr


def test_a_broken_gymnax_corner_leaves_the_environments_and_registering_names_it():
    # As on a machine where six is missing: `import gymnax` fails inside one of gymnax's own environments,
    # which wrl_jax's environments do not load; registering with gymnax imports it, and says what is missing.
    done = _python(
        "import sys\n"
        "sys.modules['six'] = None\n"
        "import wrl_jax\n"
        "assert 'Warehouse-8x8-v0' in wrl_jax.registered_names()\n"
        "env, params = wrl_jax.make('Warehouse-8x8-v0')\n"
        "import jax\n"
        "env.reset(jax.random.key(0), params)\n"
        "wrl_jax.register_with_gymnax()\n"
    )
    assert done.returncode != 0
    message = done.stderr.strip().splitlines()[-1]
    assert message.startswith("ImportError: wrl_jax registers its environments with gymnax, and `import gymnax` failed")
    assert "`pip install six`" in message and "make install" in message


@pytest.mark.parametrize("name", ["SPEC.md", "FLEET_SPEC.md", "CONTINUOUS_SPEC.md"])
def test_contracts_in_docs_equal_the_shared_copies(name):
    ours = ROOT / "docs" / name
    assert ours.is_file(), f"docs/{name} is missing: users have no ../shared"
    shared = ROOT.parent / "shared" / name
    if not shared.is_file():
        pytest.skip("no ../shared beside this checkout (a user's clone)")
    assert ours.read_text() == shared.read_text(), f"docs/{name} differs from ../shared/{name}"

"""``hinfnn keys``, ``scenarios`` and ``cache``: what a scenario accepts, what ships, the
compilation cache."""

from __future__ import annotations

from ._common import size_text


def keys(args) -> int:
    from ..scenario import keys as scenario_keys

    for key, doc, allowed, default in scenario_keys():
        print(f"{key:<40} {doc}  [{allowed}; default {default}]")
    return 0


def scenarios(args) -> int:
    from ..scenario import Scenario, scenario_names

    for name in scenario_names():
        sc = Scenario.load(name, check=False)
        print(f"{name:<20} {sc.description}")
    return 0


def cache(args) -> int:
    """Show (default), clear (``--clear``) or locate (``--path``) the compilation cache."""
    from .. import _cache

    folder = _cache.cache_dir()
    if args.path:
        if folder is not None:
            print(folder)
        return 0
    if folder is None:
        print(f"compilation cache: off ({_cache.cache_disabled_reason()})"
              + ("; nothing to clear" if args.clear else ""))
        return 0
    if args.clear:
        n, _ = _cache.cache_size()
        removed = _cache.clear_cache()
        print(f"removed {n} files ({size_text(removed)}) from {folder}")
        return 0
    n, size = _cache.cache_size()
    print(f"compilation cache: {folder}\nfiles: {n}\nsize:  {size_text(size)}")
    return 0

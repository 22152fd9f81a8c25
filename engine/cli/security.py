"""``vgr certs make RECIPE --out DIR``: a development CA and a certificate for every process and
observer of a recipe's ``security:`` block (engine.security.certs; docs/security.md)."""

from __future__ import annotations

import argparse
from pathlib import Path

from rich.console import Console

from engine.exit_codes import ExitCode
from engine.recipe.endpoint_syntax import HOST_PORT
from engine.recipe.model import load_recipe
from engine.security.certs import Identity, write_bundle

out = Console(highlight=False)


def _hosts(endpoints: list[str]) -> list[str]:
    """Host names and addresses of host:port endpoints (a listener's certificate must name them)."""
    hosts = []
    for e in endpoints:
        proto, _, rest = e.partition("/")
        if proto in HOST_PORT:
            host = rest.split("?")[0].split("#")[0].rpartition(":")[0].strip("[]")
            if host and host not in ("0.0.0.0", "::"):
                hosts.append(host)
    return hosts


def cmd_certs_make(args: argparse.Namespace) -> int:
    loaded = load_recipe(Path(args.recipe), args.param or [])
    recipe = loaded.recipe
    observers = [*recipe.security.observers, *recipe.security.controllers] if recipe.security else []
    observers += [o for o in args.observer or [] if o not in observers]
    identities = [
        Identity(p, tuple(_hosts(recipe.zenoh_for(p).listen or []) + (args.host or [])))
        for p in recipe.processes_used()
    ]
    identities += [Identity(o, tuple(args.host or [])) for o in observers]
    try:
        written = write_bundle(
            Path(args.out), identities, ca_name=f"vgr development CA ({recipe.name})", days=args.days
        )
    except (FileExistsError, PermissionError) as exc:
        out.print(f"[red]refused[/]: {exc}")
        return ExitCode.INVALID
    names = ", ".join(i.name for i in identities)
    out.print(f"wrote {len(written)} files to {args.out}: CA, {len(identities)} identities ({names})")
    out.print(f"keep {Path(args.out) / 'ca.key'} off the cell: it can make new identities")
    if recipe.security is None:
        out.print("the recipe has no security: block yet; add one naming this folder (docs/security.md)")
    return ExitCode.OK


def add_verbs(sub: argparse._SubParsersAction) -> None:  # type: ignore[type-arg]
    p = sub.add_parser("certs", help="development certificates for a recipe's security: block")
    verbs = p.add_subparsers(dest="certs_verb", required=True)
    m = verbs.add_parser("make", help="a CA and one certificate per process and observer (CN = its name)")
    m.add_argument("recipe", help="recipe YAML file")
    m.add_argument("-p", "--param", action="append", metavar="KEY=VALUE", help="recipe override (as for vgr run)")
    m.add_argument("--out", required=True, help="a new (or empty) folder to write into")
    m.add_argument("--observer", action="append", metavar="NAME", help="also make a read-only observer identity")
    m.add_argument("--host", action="append", metavar="HOST", help="another host name or address for every certificate")
    m.add_argument("--days", type=int, default=365, help="validity in days (default 365)")
    m.set_defaults(func=cmd_certs_make)

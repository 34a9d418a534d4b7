"""``teleop keys``: create, authorise, list and revoke the bus's CURVE keys.

Only public keys are ever printed. Layout of a keys directory and how the bus uses it:
:mod:`teleop.bus.security`. How to set up one host and two: :data:`SETUP`, which ``teleop keys
--help`` prints.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
from pathlib import Path

from teleop.bus.security import (
    AuthorizedKey,
    KeyListing,
    authorize_key,
    init_keys,
    list_keys,
    revoke_key,
)

RESTART_NOTE = "restart the bus servers (the binding nodes) for the change to take effect"

SETUP = """\
one host:
  teleop keys init /etc/teleop/keys          # server + client pairs, client authorised
  # then set bus.keys_dir = "/etc/teleop/keys" in the settings TOML

two hosts (robot host R: robot node; operator host O: console, estimator, renderer). Every
process binds an endpoint, and all of them serve with the one server key pair, so both hosts
need its secret certificate and each admits the other's client key:
  teleop keys init /etc/teleop/keys                           # on R
  # copy R's server.key and server.key_secret to O (e.g. scp -p), then on O:
  teleop keys init ~/keys --server-cert server.key
  install -m600 server.key_secret ~/keys/                     # O binds too
  teleop keys add ~/keys r-client.key --name robot            # on O: R's client.key
  teleop keys add /etc/teleop/keys o-client.key --name operator   # on R: O's client.key
  # set bus.keys_dir on both hosts; restart R's robot node after the add there

a host that binds nothing (one that runs only teleop record): init --server-cert alone, then
`teleop keys add` its client.key on every host that binds.
"""


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.epilog = SETUP
    parser.formatter_class = argparse.RawDescriptionHelpFormatter
    actions = parser.add_subparsers(
        dest="action", metavar="ACTION", title="actions", help="what to do with the keys directory"
    )
    actions.required = True
    init = actions.add_parser(
        "init",
        help="create a keys directory: server and client key pairs "
        "(secret files mode 0600), the client authorised in DIR/authorized/",
    )
    init.add_argument("dir", metavar="DIR", help="new keys directory (created with mode 0700)")
    init.add_argument(
        "--server-cert",
        metavar="CERT",
        help="join an existing bus: trust this server public certificate instead of creating a "
        "server key pair; to bind too (any host running the robot node, console, estimator or "
        "renderer), also install that server's server.key_secret in DIR with mode 0600 "
        "(see `teleop keys --help`)",
    )
    add = actions.add_parser("add", help="authorise a client's public certificate")
    add.add_argument("dir", metavar="DIR", help="keys directory made by `teleop keys init`")
    add.add_argument(
        "cert", metavar="CERT", help="the client's public certificate (.key, never .key_secret)"
    )
    add.add_argument("--name", help="name to authorise it under (default: CERT's file stem)")
    listing = actions.add_parser("list", help="print the public keys and the authorised clients")
    listing.add_argument("dir", metavar="DIR", help="keys directory")
    revoke = actions.add_parser("revoke", help="stop admitting an authorised client")
    revoke.add_argument("dir", metavar="DIR", help="keys directory")
    revoke.add_argument(
        "name", metavar="NAME", help="authorised client name, as `teleop keys list` shows it"
    )
    for sub in (init, add, listing, revoke):
        sub.add_argument(
            "--json",
            action="store_true",
            help="print one JSON object (public keys only) on the last line",
        )


def _print_listing(listing: KeyListing) -> None:
    role = "bind and connect" if listing.can_serve else "connect only (no server secret key)"
    print(f"keys directory  {listing.keys_dir}  ({role})")
    print(f"server public   {listing.server_public_key}")
    print(f"client public   {listing.client_public_key}")
    print(f"authorised clients ({len(listing.authorized)}):")
    for key in listing.authorized:
        print(f"  {key.name:24s} {key.public_key}")


def run(args: argparse.Namespace) -> int:
    result: KeyListing | AuthorizedKey
    if args.action == "init":
        result = init_keys(args.dir, server_cert=args.server_cert)
        if not args.json:
            _print_listing(result)
            print(f"next: set bus.keys_dir = {str(Path(args.dir).resolve())!r} in the settings TOML")
    elif args.action == "add":
        result = authorize_key(args.dir, args.cert, name=args.name)
        if not args.json:
            print(f"authorised {result.name} {result.public_key}; {RESTART_NOTE}")
    elif args.action == "list":
        result = list_keys(args.dir)
        if not args.json:
            _print_listing(result)
    else:
        own_key = list_keys(args.dir).client_public_key
        result = revoke_key(args.dir, args.name)
        if not args.json:
            print(f"revoked {result.name} {result.public_key}; {RESTART_NOTE}")
        if result.public_key == own_key:
            print(f"warning: {result.name!r} is this directory's own client key: the processes that use "
                  f"{args.dir} as bus.keys_dir can no longer connect to its servers", file=sys.stderr)
    if args.json:
        print(json.dumps({"action": args.action, **dataclasses.asdict(result)}))
    return 0

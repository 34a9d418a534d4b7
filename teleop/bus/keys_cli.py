"""``teleop keys``: create, authorise, list and revoke the bus's CURVE keys.

Only public keys are ever printed. Layout of a keys directory and how the bus uses it:
:mod:`teleop.bus.security`. A typical setup::

    teleop keys init /etc/teleop/keys          # server + client pairs, client authorised
    # then set bus.keys_dir = "/etc/teleop/keys" in the settings TOML

    # a second host that only connects: its own client, trusting the robot's server key
    teleop keys init ~/keys --server-cert server.key     # on the operator host
    teleop keys add /etc/teleop/keys client.key --name operator   # on the robot host
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


def add_arguments(parser: argparse.ArgumentParser) -> None:
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
        help="join an existing bus: trust this server public certificate instead "
        "of creating a server key pair (the node can then connect, not bind)",
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

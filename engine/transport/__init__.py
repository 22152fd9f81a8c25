"""How stages talk: the zenoh bus and its session configuration, the wire format of a message
(header attachment + payload), shared memory, endpoints and private sockets, discovery of the
processes of a run, peer tokens and the access-control list generated from a recipe.

Layer: may import the engine's top level, messages, recipe and security; never run, recording or cli.
"""

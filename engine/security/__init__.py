"""Certificates (:mod:`engine.security.certs`, ``vgr certs make``) and the recipe's ``security:``
settings turned into TLS identities (:mod:`engine.security.tls`)."""

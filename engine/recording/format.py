"""The recording format's names: the channels vgr adds to an MCAP file beside the stages' own.

A leaf module (it imports nothing), so the reader, replay and tools that only read a file need
neither the recorder nor zenoh nor the runner. The stages' channels are ``/<stage>/<port>``; the
replies a stage received from a service are ``/<stage>/_svc/<client>`` (:func:`service_topic`).
"""

from __future__ import annotations

TOPIC_DELIVERIES = "/_vgr/deliveries"  # the order in which every stage received every message
TOPIC_FINISH = "/_vgr/finish"  # the run summary, written last
TOPIC_RUN = "/_vgr/run"  # the resolved recipe and the package versions, written first
TOPIC_SERVED = "/_vgr/served"  # every call a service answered, with the reply


def service_topic(stage: str, client: str) -> str:
    """The channel of the replies stage *stage* received from the service it calls as *client*."""
    return f"/{stage}/_svc/{client}"

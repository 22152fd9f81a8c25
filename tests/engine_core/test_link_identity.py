"""engine.transport.link_identity and the peer watch's held claims, on links given by the test
(what ``Session.info.links()`` returns): which claims are taken, refused or held, and why."""

from __future__ import annotations

from dataclasses import dataclass

from engine.transport.link_identity import LinkFacts, LinkIdentity, endpoint_addresses
from engine.transport.peers import PeerWatch

SOCK = "unixsock-stream//run/user/0/vgr/r1/cell.sock"


def identity(links: list[LinkFacts], secured: bool = False) -> LinkIdentity:
    return LinkIdentity(lambda: links, "vision", secured=secured, dialled={SOCK: "cell"})


def test_without_security_the_session_on_the_process_endpoint_is_the_process():
    assert identity([LinkFacts("z1", SOCK, None)]).verdict("cell", "z1").accepted
    refused = identity([LinkFacts("z1", SOCK, None), LinkFacts("z9", "unixsock-stream/8f1e", None)]).verdict(
        "cell", "z9"
    )
    assert not refused.accepted and "z9" in refused.refusal and "z1" in refused.refusal and SOCK in refused.refusal
    held = identity([LinkFacts("z9", "unixsock-stream/8f1e", None)]).verdict("cell", "z9")  # nothing on cell's socket
    assert held.pending and not held.refusal
    # a process whose endpoint this session does not dial is taken on its claim
    assert identity([]).verdict("robot", "z4").accepted


def test_with_security_the_certificate_decides_and_a_copied_one_is_refused():
    links = [LinkFacts("z1", "tls/127.0.0.1:7447", "cell")]
    assert identity(links, secured=True).verdict("cell", "z1").accepted
    assert identity([], secured=True).verdict("cell", "z1").accepted  # reached through another process
    copied = identity([*links, LinkFacts("z2", "tls/127.0.0.1:50312", "cell")], secured=True)
    assert "two sessions with one identity" in copied.verdict("cell", "z1").refusal
    assert copied.shared_certificates(["cell", "vision"], "zv") == {"cell": {"z1", "z2"}}
    mine = identity([LinkFacts("z3", "tls/127.0.0.1:50314", "vision")], secured=True)  # this process's certificate
    assert mine.shared_certificates(["cell", "vision"], "zv") == {"vision": {"z3", "zv"}}
    other = identity([LinkFacts("z1", "tls/127.0.0.1:7447", "vision")], secured=True)
    assert "shows the certificate of ['vision']" in other.verdict("cell", "z1").refusal
    assert identity(links).shared_certificates(["cell"], "zv") == {}  # without security: none


def test_an_ip_endpoint_matches_the_address_zenoh_reports():
    assert "tcp/127.0.0.1:7447" in endpoint_addresses("tcp/localhost:7447")
    assert endpoint_addresses("tcp/127.0.0.1:7447#iface=lo") == {"tcp/127.0.0.1:7447"}
    assert "tcp/[::1]:7447" in endpoint_addresses("tcp/[::1]:7447")
    assert endpoint_addresses(SOCK) == {SOCK}
    assert "tcp/127.0.0.1:7447" in endpoint_addresses("tcp/0.0.0.0:7447")  # (zenoh reports loopback)
    assert "tcp/[::1]:7447" in endpoint_addresses("tcp/[::]:7447")
    links: list[LinkFacts] = []
    named = LinkIdentity(lambda: links, "b", secured=False, dialled={"tcp/localhost:7447": "a"})
    # over IP, a claim is taken while no link shows the endpoint's address (it may be spelled
    # otherwise: a run never waits for a link it cannot recognise), and checked once one does
    assert named.verdict("a", "z9").accepted
    links.append(LinkFacts("z1", "tcp/127.0.0.1:7447", None))
    assert named.verdict("a", "z1").accepted and named.verdict("a", "z9").refusal


@dataclass
class Sample:
    key_expr: str
    put: bool = True

    @property
    def kind(self):
        import zenoh

        return zenoh.SampleKind.PUT if self.put else zenoh.SampleKind.DELETE


def test_a_held_claim_keeps_its_markers_is_taken_once_confirmed_and_dropped_when_it_goes():
    links: list[LinkFacts] = []
    refused: list[tuple[str, str, str]] = []
    watch = PeerWatch("r1", verify=identity(links).verdict, on_refused=lambda *a: refused.append(a))
    key = "vgr/r1/_peer/cell/z1/e1"
    watch.on_sample(Sample(f"{key}/started/d1"))  # (history may bring a marker before its token)
    watch.on_sample(Sample(key))
    assert watch.owner("cell") is None and watch.held() == {"cell": ["z1"]}
    assert watch.wait_for({"cell"}, 0.2) == {"cell"}
    links.append(LinkFacts("z1", SOCK, None))  # the link to cell's socket comes up
    assert watch.wait_for({"cell"}, 2.0) == set()
    assert watch.owner("cell") == "z1" and watch.held() == {} and watch.wait_for({"cell"}, 0.1, "started") == set()
    # another session claiming cell now: refused, named once, and its markers ignored
    watch.on_sample(Sample("vgr/r1/_peer/cell/z9/e9"))
    watch.on_sample(Sample("vgr/r1/_peer/cell/z9/e9/done"))
    assert [r[:2] for r in refused] == [("cell", "z9")] and watch.owner("cell") == "z1"
    # this process's own name from another session is not taken for it (nor is it an alarm here)
    mine = PeerWatch("r1", own=("vision", "zv"))
    mine.on_sample(Sample("vgr/r1/_peer/vision/z666/e6"))
    mine.on_sample(Sample("vgr/r1/_peer/vision/zv/e1"))
    assert mine.owner("vision") == "zv" and mine.process_of("z666") is None
    # a claim whose token goes while held is forgotten
    watch2 = PeerWatch("r1", verify=identity([]).verdict)
    watch2.on_sample(Sample(key))
    watch2.on_sample(Sample(key, put=False))
    assert watch2.held() == {} and watch2.owner("cell") is None


def test_a_process_that_left_is_still_known_as_the_sender_of_its_last_message():
    # zenoh sends a token's removal at control priority, ahead of data queued before it: a stop a
    # process broadcast as it left can arrive after its token went
    watch = PeerWatch("r1")
    key = "vgr/r1/_peer/cell/z1/e1"
    watch.on_sample(Sample(key))
    watch.on_sample(Sample(f"{key}/done"))
    watch.on_sample(Sample(key, put=False))
    assert watch.process_of("z1") is None and watch.owner("cell") is None
    assert watch.process_of("z1", gone=True) == "cell" and watch.process_of("z9", gone=True) is None


def test_a_member_that_says_its_run_stopped_is_named_once_and_a_stranger_never():
    stopped: list[str] = []
    watch = PeerWatch("r1", on_stopped=stopped.append)
    key = "vgr/r1/_peer/cell/z1/e1"
    watch.on_sample(Sample(key))
    watch.on_sample(Sample("vgr/r1/_peer/cell/z9/e9/stopped"))  # not the accepted session of cell
    assert stopped == []
    watch.on_sample(Sample(f"{key}/stopped"))
    watch.on_sample(Sample(f"{key}/stopped"))
    watch.on_sample(Sample(f"{key}/done"))
    assert stopped == ["cell"]

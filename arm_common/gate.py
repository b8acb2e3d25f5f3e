"""Hold a node's first publications until named subscribers have matched them.

A DDS publisher delivers a (volatile) message only to the readers it has matched when it
publishes; what it sends before a reader's discovery reaches it is never delivered to that
reader. A recorder started first therefore misses, and counts lost, the first messages of a
node that starts after it and publishes at once (the simulator's first state, the
controller's first answers), however the start-up is ordered: the new node may hear the
simulator before the recorder's announcement reaches it. ``ros2 topic pub
--wait-matching-subscriptions`` has the same remedy for one topic.

:class:`SubscriberGate` is that remedy for a node: it opens once, for every one of the
node's gated publishers, each named node has a subscription on the topic in the ROS graph
and the publisher has matched at least as many subscriptions as the graph lists (so a
listed subscription is matched, not only discovered). It never closes again. The wall clock
only decides how often the node asks and when it says it is still waiting.
"""

from __future__ import annotations

import time
from collections.abc import Sequence

from arm_common.params import ParamSpec

#: s (wall) of waiting after which the wait is reported as a problem (WARN), and again
#: after each further REPORT_EVERY s: a node waiting this long for a subscriber that should
#: come quickly is worth a look (is it running? on this domain, in this namespace?).
REPORT_EVERY = 5.0

#: The parameter every gated node declares (one source for its doc and default).
WAIT_FOR_NODES = ParamSpec(
    'wait_for_nodes', 'strings', [],
    'Nodes (names, or /namespace/name) that must have matched each output stream of this '
    'node before it publishes there for the first time, e.g. [recorder] so a bag started '
    'first holds every message; [] = publish at once. Read-only', read_only=True)


def _matches(wanted: str, name: str, namespace: str) -> bool:
    if '/' not in wanted:
        return name == wanted
    fqn = (namespace.rstrip('/') + '/' + name) if namespace != '/' else '/' + name
    return fqn == '/' + wanted.strip('/')


def unmatched(node, pub) -> str | None:
    """``'<n> of <m> subscriptions matched on <topic>'`` when ``pub`` has matched fewer
    subscriptions than ``node``'s graph lists on its topic (a volatile message published
    now would miss the rest), else None."""
    listed = len(node.get_subscriptions_info_by_topic(pub.topic_name))
    matched = pub.get_subscription_count()
    if matched < listed:
        return f'{matched} of {listed} subscriptions matched on {pub.topic_name}'
    return None


class SubscriberGate:
    """``node``'s ``publishers`` wait for ``nodes``' subscriptions (see the module)."""

    def __init__(self, node, publishers: Sequence, nodes: Sequence[str]) -> None:
        self.node = node
        self.publishers = list(publishers)
        self.nodes = [n for n in nodes if n]
        self.opened = not self.nodes
        self.since: float | None = None  # wall s the node first asked
        self.reported = 0.0  # wall s waited at the last report

    def missing(self) -> list[str]:
        """What is not there yet, as ``'<node> on <topic>'`` (or ``'<n> of <m> subscriptions
        matched on <topic>'``); [] once open."""
        if self.opened:
            return []
        gaps: list[str] = []
        for pub in self.publishers:
            topic = pub.topic_name
            infos = self.node.get_subscriptions_info_by_topic(topic)
            for wanted in self.nodes:
                if not any(_matches(wanted, i.node_name, i.node_namespace) for i in infos):
                    gaps.append(f'{wanted} on {topic}')
            gap = unmatched(self.node, pub)
            if gap:
                gaps.append(gap)
        return gaps

    def open(self) -> bool:
        """True once every named node's subscriptions are matched (then always)."""
        if not self.opened and not self.missing():
            self.opened = True
        return self.opened

    def ready(self, diag, what: str) -> bool:
        """:meth:`open`, saying so on ``diag`` (:class:`arm_common.node.Diagnostics`):
        when the node first waits (log, INFO), when it opens after a wait (INFO), and every
        :data:`REPORT_EVERY` s of waiting (``waiting_for_subscribers``, WARN). ``what`` is
        what waits (e.g. ``'the first state'``)."""
        if self.opened:
            return True
        now = time.monotonic()
        gaps = self.missing()
        log = diag.node.get_logger()
        if not gaps:
            self.opened = True
            if self.since is not None:
                log.info(f'{", ".join(self.nodes)} matched: {what} goes out after '
                         f'{now - self.since:.2f} s (wall)')
            return True
        if self.since is None:
            self.since = now
            log.info(f'{what} waits for {", ".join(gaps)} (wait_for_nodes)')
        elif now - self.since - self.reported >= REPORT_EVERY:
            self.reported = now - self.since
            diag.problem('waiting_for_subscribers', f'{what} has waited {self.reported:.0f} s '
                         f'(wall) for {", ".join(gaps)} (wait_for_nodes: is it running, on '
                         'this domain and namespace?)', waited_wall=f'{self.reported:.1f}')
        return False

"""kmock's request dispatch at a constant cost per request: test scaffolding for `kube_emulator.Emulator`.

kmock 0.8 picks a reaction for a request by asking each reaction's view `request in view`, and a view answers
that by iterating every request the handler holds (every one in flight, open watches included) through its
filters until it meets this one by identity: O(reactions x requests in flight) per request, so the emulator's
CPU grew with the operator's backlog (45 % of it at 5,000 NetApps). `FastDispatch` answers the same question for
the one request by walking the view's chain (filters, priorities, groups) instead, and falls back to kmock's scan
for a view whose answer depends on other requests (a slice: `kmock['get'][:1]`, a live stream).
"""

from __future__ import annotations

from typing import Any

import kmock

# The criteria fields whose values come from a small set (a method, an action, a resource): their check is
# remembered per criteria and value. kmock's matching of one value is costly (enums compiled into regular
# expressions, runtime protocol checks) and a request meets a dozen reactions, most of which differ in these.
# Beside them, the criteria's other fields (checked on every request unless all are unset).
SMALL_FIELDS = {
    kmock.HTTPCriteria: ("method",),
    kmock.K8sCriteria: ("method", "action", "resource", "subresource"),
}
OTHER_FIELDS = {
    kmock.HTTPCriteria: ("path", "text", "body", "data", "params", "cookies", "headers"),
    kmock.K8sCriteria: ("namespace", "name"),
}


class CriteriaMemo:
    """`criteria(request)` with the small fields' verdict remembered: a request that fails them is refused from
    the memo; one that passes gets the whole check (its names and paths are one per object, not remembered)."""

    def __init__(self) -> None:
        self._verdicts: dict[tuple[int, tuple[Any, ...]], bool] = {}
        self._alive: dict[int, kmock.Criteria] = {}  # so that the ids in the keys are not reused
        self._only: dict[int, bool] = {}  # criteria id -> whether it sets nothing but small fields

    def __call__(self, criteria: kmock.Criteria, request: kmock.Request) -> bool:
        fields = SMALL_FIELDS.get(type(criteria))
        if fields is None:
            return bool(criteria(request))
        values = tuple(getattr(request, field) for field in fields)
        key = (id(criteria), values)
        try:
            verdict = self._verdicts.get(key)
        except TypeError:  # an unhashable value: no memo
            return bool(criteria(request))
        if verdict is None:
            verdict = all(criteria._check(getattr(criteria, f), v) for f, v in zip(fields, values, strict=True))
            self._verdicts[key] = verdict
            self._alive[id(criteria)] = criteria
        if not verdict:
            return False
        # Only small fields set (the emulator's own `fallback[action]` reactions): the verdict is the answer.
        return self._small_only(criteria) or bool(criteria(request))

    def _small_only(self, criteria: kmock.Criteria) -> bool:
        known = self._only.get(id(criteria))
        if known is None:
            known = self._only[id(criteria)] = all(
                getattr(criteria, f) is Ellipsis for f in OTHER_FIELDS[type(criteria)]
            )
        return known


def sees(view: kmock.View, request: kmock.Request, root: kmock.Root, memo: CriteriaMemo | None = None) -> bool:
    """Whether `view` holds `request`, which has just arrived at `root`: the answer of kmock's `request in view`
    for views made of filters, priorities, groups and exclusions, without iterating the other requests."""
    match view:
        case kmock.Root():
            return view is root
        case kmock.Filter():
            # The source first: a chained callable filter sees only what the filters before it let through.
            if not sees(view._source, request, root, memo):
                return False
            return memo(view.criteria, request) if memo is not None else bool(view.criteria(request))
        case kmock.Slicer() | kmock.Stream():
            return request in view  # depends on the other requests: kmock's own scan
        case kmock.Exclusion():
            return sees(view._source, request, root, memo) and not any(
                sees(v, request, root, memo) for v in view._exclusions
            )
        case kmock.Reaction() | kmock.Priority():
            return sees(view._source, request, root, memo)
        case kmock.OrGroup():
            return any(sees(v, request, root, memo) for v in view._sources)
        case kmock.AndGroup():
            return all(sees(v, request, root, memo) for v in view._sources)
    return request in view  # a view this module does not know: kmock's own answer


class FastDispatch(kmock.RawHandler):
    """kmock's `RawHandler._handle` (the reaction with the highest priority whose view holds the request, the
    first one declared among equals) with the reactions sorted once per set of reactions, not per request, and
    membership decided by `sees`. Mixed in after `kmock.KubernetesEmulator`, whose `_handle` calls it."""

    async def _handle(self, request: kmock.Request) -> Any:
        memo = getattr(self, "_criteria_memo", None)
        if memo is None:
            memo = self._criteria_memo = CriteriaMemo()
        for payload in self._ordered_payloads():
            if sees(payload._source, request, self, memo) and not payload._disabled.is_set():
                try:
                    return await payload(request)
                except kmock.ReactionMismatchError:  # either mismatch or depletion
                    payload._disabled.set()
                except NotImplementedError:  # matched, but non-actionable (nothing to respond with)
                    pass
        raise NotImplementedError("Undefined server behaviour: no reaction matches the request.")

    def _ordered_payloads(self) -> list[kmock.Reaction]:
        key = tuple(map(id, self._payloads))
        # The cached order holds the reactions, so their ids are not reused while it is kept.
        cached = getattr(self, "_fast_dispatch_order", None)
        if cached is None or cached[0] != key:
            # As kmock: priorities padded with zeroes to one length, the highest first, a stable sort.
            priorities = [payload.priorities for payload in self._payloads]
            width = max((len(p) for p in priorities), default=0)
            padded = [tuple(-p for p in priority) + (0,) * (width - len(priority)) for priority in priorities]
            order = sorted(range(len(padded)), key=padded.__getitem__)
            cached = (key, [self._payloads[i] for i in order])
            self._fast_dispatch_order = cached
        return cached[1]

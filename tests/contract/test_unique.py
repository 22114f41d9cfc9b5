"""first_of_each_id: the manifests' one rule for repeated ids (campaign runs, pool trials)."""

from types import SimpleNamespace as E

from workbench.contract.unique import first_of_each_id


def test_first_kept_repeats_reported_in_the_files_order_unparsed_skipped():
    log = []

    def parsed():
        for i, item in enumerate([("a", 1), ("b", 2), None, ("a", 3), ("c", 4), ("b", 5)]):
            log.append(f"parse #{i}")            # errors collected while parsing stay in order with the repeats
            yield i, None if item is None else E(id=item[0], v=item[1])

    got = first_of_each_id(parsed(), lambda i, e: log.append(f"repeat #{i} {e.id}={e.v}"))
    assert [(e.id, e.v) for e in got] == [("a", 1), ("b", 2), ("c", 4)]
    assert log == ["parse #0", "parse #1", "parse #2", "parse #3", "repeat #3 a=3", "parse #4", "parse #5",
                   "repeat #5 b=5"]

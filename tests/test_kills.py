"""Kill a real run at 20 points (SIGKILL at random moments and inside checkpoint, field,
CSV and run.json writes; SIGTERM and SIGINT), resume after each, and check that the outputs
are bit-identical to an uninterrupted run (femphase.testing.faults)."""

from femphase.testing.faults import KILLS, SCENE, campaign

#: Exit codes of a stopped run: SIGKILL; SIGINT/SIGTERM handled (130/143, documented in
#: femphase.cli); SIGINT/SIGTERM arriving while Python still imports, before the handler
#: exists (the process ends as the signal's default; it had written nothing yet).
STOPPED = {-9, 130, 143, -2, -15}


def test_twenty_kills_and_resumes_give_the_uninterrupted_outputs(tmp_path):
    result = campaign(SCENE, tmp_path, kills=20, seed=0)
    # attempts whose run finished before the stop came are retried in a new run, not counted
    events = [event for event in result["events"] if event["stopped"]]
    assert result["kill_points"] == len(events) >= 20
    assert result["differences"] == []
    assert all(event["exit_code"] in STOPPED for event in events), events
    assert all(event["exit_code"] == 0 for event in result["events"] if not event["stopped"])
    stops = {event["kind"] for event in events if not event["kind"].startswith("failpoint")}
    failpoints = {event["kind"].split()[1].split(":")[0] for event in events if event["kind"].startswith("failpoint")}
    assert stops == {k for k in KILLS if not k.startswith("failpoint")}
    assert failpoints == {k.split(":")[1] for k in KILLS if k.startswith("failpoint")}
    handled = [e for e in events if e["exit_code"] in (130, 143)]
    assert handled and all(e["status"] == "interrupted" and "continue with --resume" in e["stderr"] for e in handled)

"""study next's plan: where each arm keeps a participant's learning state (the default rule of
``policies.participant_state``), and withdraw's deletion of that folder."""
from __future__ import annotations

from nao_trainer.files import PROJECT_ROOT
from nao_trainer.policies.participant_state import participant_dir, state_file
from nao_trainer.study.registry import enrol, init_study, open_study, withdraw
from nao_trainer.study.runner import plan_next

PROTOCOL = PROJECT_ROOT / "config" / "protocols" / "example-3arm.yaml"


def test_each_arm_keeps_the_participants_state_where_a_session_outside_a_study_would(tmp_path):
    root = tmp_path / "study"
    init_study(PROTOCOL, root)
    by_arm = {}
    for _ in range(6):  # one block: every arm at least once
        entry = enrol(root, "2026-12-01", "v1")
        by_arm.setdefault(open_study(root).arm_of(entry["pseudonym"]), entry["pseudonym"])
    study = open_study(root)
    sessions = study.sessions_dir.resolve()
    for arm, pseudonym in by_arm.items():
        config = plan_next(study, pseudonym, {}).config
        path = config.policy_state_file()
        if not config.policy.persists:  # schedule, random: no participant state to keep
            assert path is None
            continue
        assert path is not None and path.parent == participant_dir(sessions, pseudonym)
        # the same file a session of this policy keeps outside a study (state_path left at its default)
        assert path == state_file(config.policy.kind, None, pseudonym, sessions)
        if arm == "personalised":
            assert path.name == "personalised.json"
    pseudonym = by_arm["personalised"]
    folder = participant_dir(study.sessions_dir, pseudonym)
    folder.mkdir(parents=True)
    (folder / "personalised.json").write_text("{}")
    _, deleted = withdraw(root, pseudonym, "delete")
    assert folder in deleted and not folder.exists()

"""The conformance checker's message-layout report (no ROS graph)."""

from types import SimpleNamespace

from dlmpc_ros.conformance import _layout_problems


def test_layout_problems_count_wrong_labels_and_malformed_messages():
    messages = [SimpleNamespace(label='O'), SimpleNamespace(label='x'),
                SimpleNamespace(label='y')]
    assert _layout_problems(messages, 'O', [None, 'wrong length', None],
                            'objective messages') == [
        "2 of 3 objective messages have the layout label 'x'; expected 'O'",
        '1 of 3 objective messages are malformed (first: wrong length)']
    assert _layout_problems(messages[:1], 'O', [None]) == []

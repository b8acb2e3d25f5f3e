"""``arm-sim check``: grade any controller over its topics (docs/check.md).

``suite`` reads and validates a suite file (pure), ``grade`` turns an analysed bag into
pass/fail per metric (pure), ``output`` writes the table, JUnit XML and the Markdown
report (pure), ``harness`` starts the nodes around the user's controller and runs each
scenario, ``reference_node`` is the per-state reference stream the harness publishes, and
``cli`` the sub-command. Importing this package imports nothing heavy.
"""

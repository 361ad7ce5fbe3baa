"""Independent work items run in-process or on Dask workers, with per-item records for resuming.

See docs/cluster.md.
"""

from ._arguments import add_executor_arguments, executor_options
from ._execute import ExecutorOptions, WorkItem, call_item, check_executor, dask_client, run_items
from ._store import ItemResult, check_inputs, item_path, read_item, write_item

__all__ = [
    "ExecutorOptions",
    "ItemResult",
    "WorkItem",
    "add_executor_arguments",
    "call_item",
    "check_executor",
    "check_inputs",
    "dask_client",
    "executor_options",
    "item_path",
    "read_item",
    "run_items",
    "write_item",
]

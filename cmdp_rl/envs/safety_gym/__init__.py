"""The Safety-Gymnasium package's own tasks on our stack: the env adapter, the import compatibility layer and the task list."""

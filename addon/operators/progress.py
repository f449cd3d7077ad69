"""What the modal, timer-driven operators (compare, bake) share."""


def end_modal(context, timer) -> None:
    """Remove the operator's timer (if any), end the progress bar and clear the status-bar text."""
    wm = context.window_manager
    if timer is not None:
        wm.event_timer_remove(timer)
    wm.progress_end()
    if context.workspace is not None:
        context.workspace.status_text_set(None)

"""What the modal, timer-driven operators (compare, bake) share."""


def begin_modal(op, context, interval: float, total: int):
    """Start ``op``'s timer-driven modal run: a progress bar of ``total`` steps and a timer event every ``interval``
    seconds; returns the timer (``end_modal`` ends both)."""
    wm = context.window_manager
    timer = wm.event_timer_add(interval, window=context.window)
    wm.progress_begin(0, total)
    wm.modal_handler_add(op)
    return timer


def end_modal(context, timer) -> None:
    """Remove the operator's timer (if any), end the progress bar and clear the status-bar text."""
    wm = context.window_manager
    if timer is not None:
        wm.event_timer_remove(timer)
    wm.progress_end()
    if context.workspace is not None:
        context.workspace.status_text_set(None)

"""Work in a child process seen from Blender: the job (its child, progress, cancel) and the
modal operator that polls it every 0.1 s, shows its progress in the status bar and the panel,
and cancels it on Esc. Tetrahedralize and Bake are both such jobs (ops_rig, ops_bake).

A job's poll function (poll_tetrahedralize, poll_job) is the operator's one step: 'RUNNING',
or once the child is done, whatever the job stores and its final state. Headless, tests call it
in a loop; timers never fire there."""

from __future__ import annotations

from . import runtime


class ChildJob:
    """A child process (engine.child.Child) and what the host made for it (release() frees it)."""

    def __init__(self, child):
        self.child = child
        self.error = None
        self.summary = None
        self.warnings = []  # what is suspicious but not refused, reported when the job starts

    @property
    def progress(self) -> float:
        return self.child.progress

    @property
    def message(self) -> str:
        return self.child.message

    def start(self):
        self.child.start()
        return self

    def cancel(self) -> None:
        self.child.cancel()

    def release(self) -> None:
        self.child.close()


def draw(layout, job, text: str, cancel: str, start: str, icon: str) -> None:
    """The panel's row of a job: its progress and Cancel while it runs, else its button."""
    if job is not None:
        layout.progress(factor=job.progress, text=f"{text} {job.progress * 100:.0f}% ({job.message})")
        layout.operator(cancel, icon="CANCEL")
    else:
        layout.operator(start, icon=icon)


class BackgroundOperator:
    """The modal half of an operator whose work is a ChildJob. A subclass sets `slot` (the
    runtime attribute holding its job) and defines step(context, job) -> state, status(job) ->
    status-bar text and finish(context, state) -> the operator's result."""

    slot = ""

    def report_warnings(self, job) -> None:
        for warning in job.warnings:
            self.report({"WARNING"}, warning)

    def start_modal(self, context, job):
        setattr(runtime.state, self.slot, job)
        self.job = job
        wm = context.window_manager
        wm.progress_begin(0.0, 1.0)
        self.timer = wm.event_timer_add(0.1, window=context.window)
        wm.modal_handler_add(self)
        return {"RUNNING_MODAL"}

    def modal(self, context, event):
        if getattr(runtime.state, self.slot) is not self.job:  # stopped from outside (a file was opened)
            self.stop_modal(context)
            return {"CANCELLED"}
        if event.type == "ESC":
            self.job.cancel()
        if event.type != "TIMER":
            return {"PASS_THROUGH"}
        state = self.step(context, self.job)
        if state == "RUNNING":
            context.window_manager.progress_update(self.job.progress)
            context.workspace.status_text_set(self.status(self.job))
            runtime.redraw()
            return {"PASS_THROUGH"}
        self.stop_modal(context)
        return self.finish(context, state)

    def stop_modal(self, context):
        wm = context.window_manager
        wm.event_timer_remove(self.timer)
        wm.progress_end()
        if context.workspace is not None:
            context.workspace.status_text_set(None)
        runtime.redraw()

    def cancel(self, context):
        self.job.cancel()
        self.job.release()
        if getattr(runtime.state, self.slot) is self.job:
            setattr(runtime.state, self.slot, None)
        self.stop_modal(context)

/*
 * The FMI 3.0 state table of the FMU's loader, per instance (fmi3_loader.h): the refusal of a call
 * the state forbids (fmi3Error, logged, nothing reaches Python), the slave's hand-off of its state
 * and status through the logger, and the host's log categories (fmi3SetDebugLogging is answered
 * here).  The same mechanism as FMI 2.0's (fmi2_states.c), on the shared pieces of loader_common.c.
 *
 * The hand-off.  The slave (fmu_src/fmi3_adapter.py: an FMI 3.0 face around the FMI 2.0 TableSlave,
 * its core) hands the core's state and the status of the current call over as a log message of
 * category STATUS_CATEGORY, "<state> <status>[ <reason>]", with the core's FMI 2.0 state names;
 * pythonfmu3's wrapper passes it to fmi3_relay, which consumes it (never shown to the host).  The
 * FMI 2.0 names map to FMI 3.0's states: stepComplete -> StepMode; stepFailed -> StepMode too (FMI
 * 3.0 has no stepFailed: a doStep that returns fmi3Discard leaves the FMU "in the same state as
 * before the call", and the adapter moves its core back to stepComplete after a discarded step);
 * error -> FMI 3.0's Terminated after an fmi3Error (S_ERROR, with the reason).
 *
 * A message of category LANE_CATEGORY hands the slave's fast lane over (fast_lane.h), as in FMI 2.0.
 */
#define _GNU_SOURCE
#include "fmi3_loader.h"

#include <stdarg.h>
#include <stdio.h>
#include <string.h>

/* FMI 3.0's names of the states (loader_common.h); a doStep that returns fmi3Discard keeps the state.
 * stepFailed never is an FMI 3.0 instance's state (stepFailed_of maps it), its name is FMI 2.0's. */
static const Dialect FMI3 = {"FMI 3.0", "fmi3Error",
                             {"Instantiated", "InitializationMode", "StepMode", "stepFailed", "Terminated",
                              "Terminated after an fmi3Error", "fatal"}, 0};

static unsigned stepfailed_is_stepmode(unsigned state) { return state == S_STEP_FAILED ? S_STEP_MODE : state; }

void fmi3_say(Instance3* in, fmi3Status status, const char* fmt, ...)
{
    char text[4096];
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(text, sizeof text, fmt, ap);
    va_end(ap);
    if (in->logger) in->logger(in->env, status, category_of(status), text);
}

int fmi3_admit(Instance3* in, const char* call, unsigned allowed, const char* note)
{
    if (in->cs.state & allowed) return 1;
    char where[1024];
    states_text(&FMI3, allowed, where, sizeof where);
    int why = in->cs.state == S_ERROR && in->cs.reason[0];
    if (note)
        fmi3_say(in, fmi3Error, "%s instance '%s': %s refused in state %s%s%s%s: %s; nothing changed (fmi3Error)",
                 in->model, in->name, call, state_text(&FMI3, in->cs.state), why ? " (" : "",
                 why ? in->cs.reason : "", why ? ")" : "", note);
    else
        fmi3_say(in, fmi3Error, "%s instance '%s': %s refused in state %s%s%s%s: FMI 3.0 allows it in %s only; "
                 "nothing changed (fmi3Error)", in->model, in->name, call, state_text(&FMI3, in->cs.state),
                 why ? " (" : "", why ? in->cs.reason : "", why ? ")" : "", where[0] ? where : "no state of this FMU");
    return 0;
}

fmi3Status fmi3_settle(Instance3* in, Transition t, fmi3Status status)
{
    return (fmi3Status)call_settle(&in->cs, &FMI3, t, status);
}

void fmi3_relay(fmi3InstanceEnvironment env, fmi3Status status, fmi3String category, fmi3String message)
{
    Instance3* in = env;
    const char* text = message ? message : "";        /* FMI 3.0: the message is plain text, no format */
    if (category && !strcmp(category, STATUS_CATEGORY)) {
        if (take_hand_off(&in->cs, text, stepfailed_is_stepmode))
            fmi3_say(in, fmi3Warning, "%s instance '%s': the slave handed over an unknown state: %s", in->model,
                     in->name, text);
        return;
    }
    if (category && !strcmp(category, LANE_CATEGORY)) {
        char why[256];
        in->lane = lane_take(text, why, sizeof why);
        if (why[0])
            fmi3_say(in, fmi3Warning, "%s instance '%s': no fast lane (%s); every call goes through Python",
                     in->model, in->name, why);
        return;
    }
    int bit = category_bit(category);
    unsigned wanted = bit >= 0 ? 1u << bit : ALL_CATEGORIES;
    /* FMI 3.0: with logging off, only the messages of fmi3Error and fmi3Fatal reach the host */
    if (in->logger && ((in->log_mask & wanted) || status >= fmi3Error))
        in->logger(in->env, status, category && category[0] ? category : category_of(status), text);
}

void lane3_drop(Instance3* in, const char* why)
{
    in->lane = NULL;
    fmi3_say(in, fmi3Warning, "%s instance '%s': fast lane dropped (%s); every call goes through Python", in->model,
             in->name, why);
}

fmi3Status fmi3_debug_logging(Instance3* in, fmi3Boolean on, size_t n, const fmi3String categories[])
{
    const char* unknown = NULL;
    if (!debug_logging(&in->log_mask, on, n, categories, &unknown)) return fmi3OK;
    fmi3_say(in, fmi3Error, "%s instance '%s': fmi3SetDebugLogging: unknown log category %s (the FMU "
             "has logStatusWarning, logStatusDiscard, logStatusError, logStatusFatal, logAll); nothing "
             "changed (fmi3Error)", in->model, in->name, unknown);
    return fmi3Error;
}

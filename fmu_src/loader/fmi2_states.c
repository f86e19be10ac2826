/*
 * The FMI 2.0 state table of the FMU's loader, per instance (fmi2_loader.h): which state an
 * instance is in, the refusal of a call the state forbids (fmi2Error, logged, nothing reaches
 * Python), the slave's hand-off of its state and status through the logger, and the host's log
 * categories (fmi2SetDebugLogging is answered here).
 *
 * The hand-off.  The loader gives pythonfmu's wrapper its own logger (fmi2_relay) and instantiates
 * it with loggingOn, so every message of the slave passes here.  A message of category
 * STATUS_CATEGORY, "<state> <status>[ <reason>]" (fmu_src/fmi_states.py: FmiStates._hand_off),
 * tells the state the slave is now in and the status the current call must return at least (3:
 * fmi2Error for a refused fmi2ExitInitializationMode or fmi2Set*); it is consumed.  The other
 * messages go to the host's logger when the host enabled logging for their category.
 */
#define _GNU_SOURCE
#include "fmi2_loader.h"

#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

/* FMI 2.0's names of the states (loader_common.h); a doStep that returns fmi2Discard ends in stepFailed */
static const Dialect FMI2 = {"FMI 2.0", "fmi2Error",
                             {"instantiated", "initializationMode", "stepComplete", "stepFailed", "terminated",
                              "error", "fatal"}, S_STEP_FAILED};

unsigned fmi2_log_mask(fmi2Boolean on) { return log_mask_of(on); }

void fmi2_say(Instance* in, fmi2Status status, const char* fmt, ...)
{
    char text[4096];
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(text, sizeof text, fmt, ap);
    va_end(ap);
    if (in->host.logger)
        in->host.logger(in->host.componentEnvironment, in->name, status, category_of(status), "%s", text);
}

int fmi2_admit(Instance* in, const char* call, unsigned allowed)
{
    if (in->cs.state & allowed) return 1;
    char where[1024];
    states_text(&FMI2, allowed, where, sizeof where);
    int why = in->cs.state == S_ERROR && in->cs.reason[0];
    fmi2_say(in, fmi2Error, "%s instance '%s': %s refused in state %s%s%s%s: FMI 2.0 allows it in %s only; "
             "nothing changed (fmi2Error)", in->model, in->name, call, state_text(&FMI2, in->cs.state),
             why ? " (" : "", why ? in->cs.reason : "", why ? ")" : "", where[0] ? where : "no state of this FMU");
    return 0;
}

void fmi2_begin(Instance* in) { call_begin(&in->cs); }

fmi2Status fmi2_settle(Instance* in, Transition t, fmi2Status status)
{
    return (fmi2Status)call_settle(&in->cs, &FMI2, t, status);
}

void fmi2_relay(fmi2ComponentEnvironment env, fmi2String name, fmi2Status status, fmi2String category,
                fmi2String message, ...)
{
    Instance* in = env;
    char text[8192];
    va_list ap;
    va_start(ap, message);
    vsnprintf(text, sizeof text, message ? message : "", ap);   /* pythonfmu escapes '%' in the text */
    va_end(ap);
    if (category && !strcmp(category, STATUS_CATEGORY)) {
        if (take_hand_off(&in->cs, text, NULL))
            fmi2_say(in, fmi2Warning, "%s instance '%s': the slave handed over an unknown state: %s", in->model,
                     in->name, text);
        return;
    }
    if (category && !strcmp(category, LANE_CATEGORY)) {
        char why[256];
        in->lane = lane_take(text, why, sizeof why);
        if (why[0])
            fmi2_say(in, fmi2Warning, "%s instance '%s': no fast lane (%s); every call goes through Python",
                     in->model, in->name, why);
        return;
    }
    int bit = category_bit(category);
    unsigned wanted = bit >= 0 ? 1u << bit : ALL_CATEGORIES;
    if (in->host.logger && (in->log_mask & wanted))
        in->host.logger(in->host.componentEnvironment, name, status, category, "%s", text);
}

void lane_drop(Instance* in, const char* why)
{
    in->lane = NULL;
    fmi2_say(in, fmi2Warning, "%s instance '%s': fast lane dropped (%s); every call goes through Python", in->model,
             in->name, why);
}

fmi2Status fmi2_debug_logging(Instance* in, fmi2Boolean on, size_t n, const fmi2String categories[])
{
    const char* unknown = NULL;
    if (!debug_logging(&in->log_mask, on, n, categories, &unknown)) return fmi2OK;
    fmi2_say(in, fmi2Error, "%s instance '%s': fmi2SetDebugLogging: unknown log category %s (the FMU "
             "has logStatusWarning, logStatusDiscard, logStatusError, logStatusFatal, logAll); nothing "
             "changed", in->model, in->name, unknown);
    return fmi2Error;
}

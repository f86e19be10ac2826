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

static const char* const STATE_NAMES[] = {
    "instantiated", "initializationMode", "stepComplete", "stepFailed", "terminated", "error", "fatal"};
#define N_STATES (sizeof STATE_NAMES / sizeof STATE_NAMES[0])

/* the log categories of pythonfmu's modelDescription (bits of Instance.log_mask, in this order) */
static const char* const CATEGORIES[] = {
    "logStatusWarning", "logStatusDiscard", "logStatusError", "logStatusFatal", "logAll"};
#define N_CATEGORIES (sizeof CATEGORIES / sizeof CATEGORIES[0])
#define ALL_CATEGORIES ((1u << N_CATEGORIES) - 1u)

static const char* state_name(unsigned state)
{
    for (unsigned k = 0; k < N_STATES; ++k)
        if (state == 1u << k) return STATE_NAMES[k];
    return "unknown";
}

static unsigned state_of(const char* name, size_t n)
{
    for (unsigned k = 0; k < N_STATES; ++k)
        if (strlen(STATE_NAMES[k]) == n && !strncmp(name, STATE_NAMES[k], n)) return 1u << k;
    return 0;
}

static int category_bit(const char* name)
{
    for (unsigned k = 0; k < N_CATEGORIES; ++k)
        if (name && !strcmp(name, CATEGORIES[k])) return (int)k;
    return -1;
}

unsigned fmi2_log_mask(fmi2Boolean on) { return on ? ALL_CATEGORIES : 0u; }

void fmi2_say(Instance* in, fmi2Status status, const char* fmt, ...)
{
    char text[4096];
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(text, sizeof text, fmt, ap);
    va_end(ap);
    static const char* const by_status[] = {"logAll", "logStatusWarning", "logStatusDiscard", "logStatusError",
                                            "logStatusFatal", "logAll"};
    if (in->host.logger)
        in->host.logger(in->host.componentEnvironment, in->name, status, by_status[status <= fmi2Pending ? status : 0],
                        "%s", text);
}

int fmi2_admit(Instance* in, const char* call, unsigned allowed)
{
    if (in->state & allowed) return 1;
    char where[1024] = "";
    for (unsigned k = 0; k < N_STATES; ++k)
        if (allowed & (1u << k))
            snprintf(where + strlen(where), sizeof where - strlen(where), "%s%s", where[0] ? ", " : "", STATE_NAMES[k]);
    int why = in->state == S_ERROR && in->reason[0];
    fmi2_say(in, fmi2Error, "%s instance '%s': %s refused in state %s%s%s%s: FMI 2.0 allows it in %s only; "
             "nothing changed (fmi2Error)", in->model, in->name, call, state_name(in->state), why ? " (" : "",
             why ? in->reason : "", why ? ")" : "", where[0] ? where : "no state of this FMU");
    return 0;
}

void fmi2_begin(Instance* in)
{
    in->reported = 0;
    in->call_status = fmi2OK;
}

fmi2Status fmi2_settle(Instance* in, Transition t, fmi2Status status)
{
    if (in->call_status > status) status = in->call_status;
    if (status >= fmi2Fatal) {
        in->state = S_FATAL;
    } else if (in->reported) {
        in->state = in->reported;
    } else if (status <= fmi2Warning) {
        static const unsigned next[] = {0, S_INITIALIZATION_MODE, S_STEP_COMPLETE, S_STEP_COMPLETE, S_TERMINATED,
                                        S_INSTANTIATED};
        if (next[t]) in->state = next[t];
    } else if (t == T_STEP && status == fmi2Discard) {
        in->state = S_STEP_FAILED;
    } else if (status == fmi2Error && (t == T_EXIT || t == T_STEP)) {
        in->state = S_ERROR;
    }
    if (in->state != S_ERROR) in->reason[0] = '\0';
    return status;
}

/* "<state> <status>[ <reason>]" from the slave */
static void take_hand_off(Instance* in, const char* text)
{
    const char* space = strchr(text, ' ');
    unsigned state = state_of(text, space ? (size_t)(space - text) : strlen(text));
    if (!state) {
        fmi2_say(in, fmi2Warning, "%s instance '%s': the slave handed over an unknown state: %s", in->model,
                 in->name, text);
        return;
    }
    in->reported = state;
    if (space) {
        char* end;
        long status = strtol(space + 1, &end, 10);
        if (end != space + 1 && status > (long)in->call_status && status <= fmi2Fatal)
            in->call_status = (fmi2Status)status;
        if (*end == ' ' && state == S_ERROR) snprintf(in->reason, sizeof in->reason, "%s", end + 1);
    }
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
        take_hand_off(in, text);
        return;
    }
    int bit = category_bit(category);
    unsigned wanted = bit >= 0 ? 1u << bit : ALL_CATEGORIES;
    if (in->host.logger && (in->log_mask & wanted))
        in->host.logger(in->host.componentEnvironment, name, status, category, "%s", text);
}

fmi2Status fmi2_debug_logging(Instance* in, fmi2Boolean on, size_t n, const fmi2String categories[])
{
    if (n == 0) {
        in->log_mask = fmi2_log_mask(on);
        return fmi2OK;
    }
    unsigned mask = 0;
    for (size_t i = 0; i < n; ++i) {
        int bit = categories ? category_bit(categories[i]) : -1;
        if (bit < 0) {
            fmi2_say(in, fmi2Error, "%s instance '%s': fmi2SetDebugLogging: unknown log category %s (the FMU "
                     "has logStatusWarning, logStatusDiscard, logStatusError, logStatusFatal, logAll); nothing "
                     "changed", in->model, in->name, categories && categories[i] ? categories[i] : "(null)");
            return fmi2Error;
        }
        mask |= 1u << bit;
    }
    in->log_mask = on ? (in->log_mask | mask) : (in->log_mask & ~mask);
    return fmi2OK;
}

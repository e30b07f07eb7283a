/* FFTW's planner is not thread-safe (plans execute safely from any thread): every plan made
 * or destroyed in the process, by the PSF builder or the drawer, takes this one lock, so that
 * set-up work may run on several threads at once. */
#ifndef WF_FFTW_LOCK_H
#define WF_FFTW_LOCK_H

void wf_fftw_lock(void);
void wf_fftw_unlock(void);

#endif

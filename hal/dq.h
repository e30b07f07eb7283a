/* Data-quality bits of a product's DQ plane, as Roman's pixel DQ (romancal /
 * roman_datamodels dqflags). One vocabulary for every layer that sets or reads them: the
 * ground-side ramp fit and assembler that write DQ, and the analysis that masks by it. */
#ifndef WF_DQ_H
#define WF_DQ_H

#define WF_DQ_DO_NOT_USE 0x1u
#define WF_DQ_SATURATED 0x2u
#define WF_DQ_JUMP_DET 0x4u
#define WF_DQ_PERSISTENCE 0x20u /* charge of an earlier exposure released here (romancal's bit) */

#endif

/* component.h of the reference source: stateless, its table is in reference_table.h. */
typedef struct {
    int unused;
} ScState;
